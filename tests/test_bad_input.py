"""Malformed scenes and command lines: status 2, one line naming the key, nothing written.

Refusals made before computing run in this process (the ``cli`` fixture); a fresh interpreter
(``tofsi(args, cwd)``) stays where the process matters: resource limits, locks held by another
process, signals, the example scripts."""

import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import scene_path

FOIL = str(scene_path("foil_in_channel"))
OPT = str(scene_path("beam_in_channel_optimization"))

CASES = [
    # (command, scene, --set overrides, key named in the message)
    ("move", FOIL, ["mesh.h_mni=0.1"], "mesh.h_mni"),                       # unknown key
    ("move", FOIL, ["mover.name=sprin"], "mover.name"),                     # misspelled mover
    ("move", FOIL, ["mesh.h_min=nan"], "mesh.h_min"),                       # NaN
    ("move", FOIL, ["mesh.h_max=inf"], "mesh.h_max"),                       # inf
    ("move", FOIL, ["mesh.h_min=-0.01"], "mesh.h_min"),                     # negative size
    ("move", FOIL, ["geometry.length=0"], "geometry.length"),               # zero size
    ("move", FOIL, ["mover.linear.poisson_ratio=0.5", "mover.name=linear"], "mover.linear.poisson_ratio"),
    ("solve", OPT, ["structure.poisson_ratio=0.5"], "structure.poisson_ratio"),
    ("move", FOIL, ["mover.yeoh.A10=0"], "mover.yeoh.A10"),                 # A10 <= 0
    ("move", FOIL, ["mover.yeoh.A10=-1"], "mover.yeoh.A10"),
    ("move", FOIL, ["mover.yeoh.kappa=-0.5"], "mover.yeoh.kappa"),          # kappa < 0
    ("optimize", OPT, ["design.volume_fraction=1.5"], "design.volume_fraction"),
    ("optimize", OPT, ["design.volume_fraction=0"], "design.volume_fraction"),
    ("optimize", OPT, ["geometry.design=[0.3, 2.7, 0.0, 0.8]"], "geometry.design"),   # outside
    ("move", FOIL, ["mover.yeoh.increments=0"], "mover.yeoh.increments"),  # zero increments
    ("move", FOIL, ["mover.spring.increments=0", "mover.name=spring"], "mover.spring.increments"),
    ("optimize", OPT, ["design.initial=nowhere/design.npy"], "design.initial"),
    ("study", FOIL, ["--sweep", "mover.layers[0]=3:1:1"], "--sweep"),
    # issue 14, item 1: --set name=. or .. would write into the working directory or above it
    ("mesh", FOIL, ["name=."], "name"),
    ("mesh", FOIL, ["name=.."], "name"),
    # item 5: validation gaps that exited 0 (or crashed later)
    ("optimize", OPT, ["design.beta=[]"], "design.beta"),                  # IndexError in optimize
    ("solve", OPT, ["fluid.inlets=[[0.5, 1.5, 1.0]]"], "fluid.inlets[0]"),  # beyond the left side
    ("solve", OPT, ["fluid.outlets=[[-0.25, 0.5, 1.0]]"], "fluid.outlets[0]"),
    ("mesh", FOIL, ["mesh.h_min=5", "mesh.h_max=5"], "mesh.h_max"),          # a 9-quad mesh
    ("mesh", FOIL, ["geometry.holes=[[0.1, 0.2, 0.1, 0.2]]"], "geometry.holes[0]"),   # no solid there
    ("study", FOIL, ["--jobs", "0", "--sweep", "mover.layers[0]=1:2:1"], "--jobs"),
    ("study", FOIL, ["--jobs", "-2", "--sweep", "mover.layers[0]=1:2:1"], "--jobs"),
    # item 6: solve's design options
    ("solve", OPT, ["--stage", "9"], "--stage"),
    ("solve", FOIL, ["--design", "design.npy"], "design.initial"),         # no design region
    # item 7: a motion that pushes the solid out of the channel, before moving
    ("move", FOIL, ["deformation.translation=0.6"], "deformation.translation"),
    ("move", FOIL, ["deformation.mode=rotation", "deformation.rotation_deg=90",
                    "geometry.solids=[[0.2, 1.8, 0.45, 0.55]]"], "deformation.rotation_deg"),
    # issue 25: passed validation, then crashed or did something else than asked
    ("solve", OPT, ["structure.clamped=[]"], "structure.clamped"),            # ValueError in concatenate
    ("optimize", OPT, ["structure.clamped=[]"], "structure.clamped"),
    ("mesh", FOIL, ['name="a\nb"'], "name"),                                   # a folder with a newline
    ("move", FOIL, ["effects.mesh_motion=spring", "mover.name=yeoh"], "mover.name"),    # last one won
    ("move", FOIL, ["mover.name=yeoh", "effects.mesh_motion=spring"], "effects.mesh_motion"),
    ("move", FOIL, ["mover.layers[0]=2"], "mover.layers[0]"),                  # "unknown key"; empty list
    ("move", FOIL, ["geometry.solids[1]=[0.1, 0.2, 0.1, 0.2]"], "geometry.solids[1]"),  # one solid only
    ("move", FOIL, ["mover.layers=[1e30]"], "mover.layers[0]"),                # exit 3 at element 0
    ("tune", FOIL, ["tune.max_factor=1e9"], "tune.max_factor"),
    ("study", FOIL, ["--max-memory", "nan", "--sweep", "mover.layers[0]=1:2:1"], "--max-memory"),
]


def tofsi(args, cwd):
    """``tofsi ARGS`` in a fresh interpreter."""
    return subprocess.run([sys.executable, "-m", "tofsi.cli", *args], capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize("command,scene,overrides,key", CASES, ids=[c[3] + ":" + " ".join(c[2]) for c in CASES])
def test_bad_values_exit_2_naming_the_key_and_write_nothing(command, scene, overrides, key, cli, tmp_path):
    args = [command, scene, "--output", "out"]
    extra = list(overrides)
    while extra:
        item = extra.pop(0)
        args += [item, extra.pop(0)] if item.startswith("--") else ["--set", item]
    run = cli(*args, cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2, run.stderr
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in run.stderr
    assert os.listdir(tmp_path) == []                                  # nothing partial


@pytest.mark.parametrize("kind", ["missing", "directory", "not toml", "binary", "device"])
def test_unreadable_or_missing_scene_files_exit_2(kind, cli, tmp_path):
    path = tmp_path / "scene.toml"
    if kind == "device":                            # said "no such file"
        path = "/dev/null"
    elif kind == "directory":
        path.mkdir()
    elif kind == "not toml":
        path.write_text("name = 'x'\n[mesh\nh_min = 1\n")
    elif kind == "binary":
        path.write_bytes(b"\xff\xfe\x00garbage\x00")
    run = cli("mesh", path, "--output", tmp_path / "out", cwd=tmp_path)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1
    assert "scene" in run.stderr and not (tmp_path / "out").exists()
    if kind == "device":
        assert "not a regular file" in run.stderr


@pytest.mark.parametrize("args", [["mesh"], ["nonsense", FOIL], ["mesh", FOIL, "--set"],
                                  ["mesh", FOIL, "--set", "no_equals_sign"], ["study", FOIL, "--jobs", "x"]])
def test_malformed_command_lines_exit_2_in_one_line(args, cli, tmp_path):
    run = cli(*args, cwd=tmp_path)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert os.listdir(tmp_path) == []


def write_design(path, kind, n):
    import numpy as np
    if kind == "outside [0, 1]":
        np.save(path, np.linspace(-0.5, 1.5, n))
    elif kind == "text":
        path.write_text("0.2\n" * n)
    elif kind == "wrong size":
        np.save(path, np.full(n + 3, 0.2))
    elif kind == "pickle":
        np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    elif kind == "directory":
        path.mkdir()
    elif kind == "strings":
        np.save(path, np.array(["0.2"] * n))
    elif kind == "complex":
        np.save(path, np.full(n, 0.2 + 0j))


@pytest.mark.parametrize("kind,says", [("strings", "holds text"), ("complex", "holds complex numbers"),
                                       ("outside [0, 1]", "not clipped"), ("text", "not a NumPy .npy file"),
                                       ("wrong size", "needs"), ("pickle", "not a NumPy .npy file"),
                                       ("directory", "is a directory")])
def test_a_bad_saved_design_exits_2_with_a_plain_message(kind, says, cli, tmp_path):
    """design.initial values outside [0, 1] were clipped silently; a text file got numpy's
    advice about pickles. Now: one line naming design.initial, saying what is wrong."""
    import tofsi as toolkit
    n = toolkit.Problem(toolkit.load_scene(OPT, ["mesh.h_min=0.1", "mesh.h_max=0.1"])).n_design
    write_design(tmp_path / "design.npy", kind, n)
    before = sorted(os.listdir(tmp_path))
    run = cli("optimize", OPT, "--output", "out", "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1",
              "--set", "design.initial=design.npy", cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "design.initial" in lines[0] and says in lines[0] and "allow_pickle" not in lines[0]
    assert sorted(os.listdir(tmp_path)) == before


def test_a_scene_with_a_byte_order_mark_is_read(cli, tmp_path):
    scene = tmp_path / "bom.toml"
    scene.write_bytes(b"\xef\xbb\xbf" + open(FOIL, "rb").read())
    run = cli("mesh", scene, "--output", "out", "--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.1",
              cwd=tmp_path)
    assert run.returncode == 0, run.stderr


def test_a_directory_given_as_the_scene_says_so(cli, tmp_path):
    (tmp_path / "scenes").mkdir()
    run = cli("mesh", "scenes", "--output", "out", cwd=tmp_path)
    assert run.returncode == 2 and "is a directory" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_a_thin_solid_is_accepted_with_a_warning(cli, tmp_path):
    run = cli("mesh", FOIL, "--output", "out", "--set", "geometry.solids=[[0.75, 1.25, 0.5, 0.5000001]]",
              "--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.1", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "WARNING" in run.stderr and "geometry.solids[0]" in run.stderr and "thinner" in run.stderr


def test_overlapping_solids_merge_into_their_union():
    """Two overlapping rectangles mesh as their union: the solid area is the union's, 0.7 x 0.2
    (the overlap counted once), and the result equals the single-rectangle scene's."""
    import numpy as np
    import tofsi as toolkit
    from tofsi.mesh.channel import build_mesh
    from tofsi.mesh.structured import SOLID
    from tofsi.mesh.quality import signed_area

    def solid_area(solids):
        scene = toolkit.load_scene(FOIL, [f"geometry.solids={solids}", "mesh.h_min=0.025", "mesh.h_max=0.05"])
        mesh = build_mesh(scene.geometry, scene.mesh)
        return signed_area(mesh.points, mesh.quads[mesh.region == SOLID]).sum()
    assert solid_area("[[0.5, 1.0, 0.4, 0.6], [0.8, 1.2, 0.4, 0.6]]") == pytest.approx(0.7 * 0.2, rel=1e-12)
    assert solid_area("[[0.5, 1.2, 0.4, 0.6]]") == pytest.approx(0.7 * 0.2, rel=1e-12)
    assert np.isclose(solid_area("[[0.5, 1.0, 0.4, 0.6], [0.8, 1.2, 0.5, 0.7]]"), 0.1 + 0.08 - 0.02)


@pytest.mark.parametrize("args", [["optimize", OPT, "--set", "design.beta=[]"], ["nonsense", FOIL]])
def test_json_errors_on_stdout(args, cli, tmp_path):
    """--json on exit 2 prints {"error": ...} on stdout (usage errors too)."""
    import json
    run = cli(*args, "--json", "--output", "out", cwd=tmp_path)
    assert run.returncode == 2
    payload = json.loads(run.stdout)
    assert payload["exit_status"] == 2 and payload["error"] in run.stderr


# ---- issue 25: results that survive a full disk -------------------------------------------------
TINY_OPT = ["--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1", "--set", "design.filter_radius=0.15",
            "--set", "design.stage_iterations=2"]


@pytest.fixture
def small_filesystem(tmp_path):
    """``make(kb)``: a tmpfs of ``kb`` KB under tmp_path (skipped where mounting is not allowed)."""
    mounted = []

    def make(kb):
        where = tmp_path / f"fs{len(mounted)}"
        where.mkdir()
        run = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={kb}k", "tmpfs", str(where)],
                             capture_output=True, text=True)
        if run.returncode != 0:
            pytest.skip(f"cannot mount a small tmpfs here ({(run.stderr or 'mount failed').strip()}); "
                        "the file-size limit tests cover the same path")
        mounted.append(where)
        return where
    yield make
    for where in mounted:
        subprocess.run(["umount", str(where)], capture_output=True)


def limited(args, cwd, max_bytes):
    """``tofsi ARGS`` with files limited to ``max_bytes`` (ulimit -f): writes beyond it fail
    with EFBIG (Python ignores SIGXFSZ)."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (max_bytes, max_bytes))
    return subprocess.run([sys.executable, "-m", "tofsi.cli", *args], capture_output=True, text=True,
                          cwd=cwd, preexec_fn=limit)


def assert_write_failure(run, folder, failed_name):
    """Exit 4 in one line naming the file, the reason and what was kept; run.json says so and
    lists exactly the complete files kept."""
    import json
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 4, run.stderr
    assert "Traceback" not in run.stderr and lines[-1].startswith("tofsi: write failure: could not write")
    line = lines[-1]
    assert failed_name in line and "kept" in line and "run.json records the failure" in line
    record = json.loads((folder / "run.json").read_text())
    assert record["exit_status"] == 4 and record["status"] == "write failure"
    assert failed_name in record["write_failure"]["file"] and record["write_failure"]["error"]
    names = sorted(n for n in os.listdir(folder) if not n.startswith("."))
    assert sorted(record["files"]) == names and all(n in line for n in names)
    assert not any(n.startswith(".") for n in os.listdir(folder))      # no temporary file, no reserve
    return record


def test_a_full_disk_is_refused_before_computing(small_filesystem, cli, tmp_path):
    """Issue 25: solve into a 200 KB file system computed, then died with OSError 28. The
    estimate (1 MB for 3200 elements) refuses it before any solve, in one line."""
    fs = small_filesystem(200)
    run = cli("solve", OPT, "--output", fs / "out", cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr          # no "solving ..." line
    assert "--output" in lines[0] and "free" in lines[0] and "MB" in lines[0]
    assert os.listdir(fs) == []


def test_a_disk_that_fills_during_the_run_ends_in_one_line_and_keeps_the_complete_files(small_filesystem,
                                                                                         tmp_path):
    """200 KB hold solution.vtu (55 KB) but not its pictures (120 KB each): exit 4 naming the
    picture; solution.vtu is complete (meshio reads it) and run.json records the failure."""
    import meshio
    fs = small_filesystem(200)
    run = tofsi(["solve", OPT, "--output", str(fs / "out"), *TINY_OPT], tmp_path)
    assert_write_failure(run, fs / "out", "solution_")
    assert "No space left on device" in run.stderr
    assert meshio.read(fs / "out" / "solution.vtu").cells[0].data.shape[1] == 9


def test_a_file_size_limit_below_the_largest_file_is_refused_before_computing(tmp_path):
    """ulimit -f 8: OSError 27 after the solve; now exit 2 naming the limit."""
    run = limited(["solve", OPT, "--output", "out"], tmp_path, 8 * 1024)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "ulimit -f" in lines[0] and "solution.vtu" in lines[0] and os.listdir(tmp_path) == []


def test_a_file_size_limit_hit_during_an_optimization_keeps_the_iterations_done(tmp_path):
    """An 80 KB limit passes the estimate (pictures about 0.1 MB, refused below 50 KB) but not
    the first design picture (about 120 KB): exit 4 naming it; the design, the history and the
    checkpoint written before it are complete, and --resume continues from them without the limit."""
    import json
    import numpy as np
    run = limited(["optimize", OPT, "--output", "out", *TINY_OPT, "--set", "optimizer.max_iter=3"],
                  tmp_path, 80 * 1024)
    assert_write_failure(run, tmp_path / "out", "design_0000.png")
    assert "File too large" in run.stderr
    history = json.loads((tmp_path / "out" / "history.json").read_text())
    assert [h["iteration"] for h in history] == [0]
    import tofsi as toolkit
    n = toolkit.Problem(toolkit.load_scene(OPT, [a for a in TINY_OPT if a != "--set"])).n_design
    design = np.load(tmp_path / "out" / "design.npy")
    assert design.shape == (n,) and 0 <= design.min() and design.max() <= 1
    with np.load(tmp_path / "out" / "checkpoint.npz") as npz:
        assert json.loads(str(npz["meta"]))["history"][0]["objective"] == history[0]["objective"]
    again = tofsi(["optimize", OPT, "--output", "out", *TINY_OPT, "--set", "optimizer.max_iter=3",
                   "--resume"], tmp_path)
    assert again.returncode == 0, again.stderr
    assert len(json.loads((tmp_path / "out" / "history.json").read_text())) == 3


def test_a_scene_name_too_long_for_a_folder_is_refused_before_computing(cli, tmp_path):
    """--set name=<300 characters> with the default results/<name>: OSError 36 after the run."""
    run = cli("move", FOIL, "--set", "name=" + "a" * 300, cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert lines[0].startswith("tofsi: error: name = ") and "300 bytes" in lines[0] and "255" in lines[0]
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("output,says", [("x" * 300 + "/out", "300 bytes"), ("a\nb", "control character"),
                                         ("/" + "d/" * 2100, "exceed")])
def test_output_folder_names_the_file_system_cannot_take_are_refused(output, says, cli, tmp_path):
    run = cli("mesh", FOIL, "--output", output, cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "--output" in lines[0] and says in lines[0] and os.listdir(tmp_path) == []


# ---- issue 25: one run per folder ---------------------------------------------------------------
def test_two_runs_started_at_once_into_one_folder_one_is_refused(tmp_path):
    """Both exited 0 and the first run's results were silently gone. Now one runs, the other
    exits 2 naming it, and the folder holds the winner's run alone."""
    import json
    args = ["optimize", OPT, "--output", "out", *TINY_OPT, "--set", "optimizer.max_iter=2", "-q"]
    runs = [subprocess.Popen([sys.executable, "-m", "tofsi.cli", *args, "--set", f"design.volume_fraction={vf}"],
                             cwd=tmp_path, stderr=subprocess.PIPE, text=True) for vf in (0.2, 0.3)]
    results = [(p.wait(), p.stderr.read()) for p in runs]
    assert sorted(status for status, _ in results) == [0, 2], results
    winner = [vf for vf, (status, _) in zip((0.2, 0.3), results, strict=True) if status == 0][0]
    loser = [err for status, err in results if status == 2][0]
    assert len(loser.strip().splitlines()) == 1 and "tofsi optimize" in loser
    record = json.loads((tmp_path / "out" / "run.json").read_text())
    assert f"design.volume_fraction={winner}" in record["overrides"] and record["exit_status"] == 0
    assert ".tofsi.lock" not in os.listdir(tmp_path / "out")


def wait_for(path, timeout=60.0):
    import time
    t0 = time.monotonic()
    while not path.exists():
        assert time.monotonic() - t0 < timeout, f"{path} did not appear"
        time.sleep(0.05)


# a run that goes on until it is signalled (no stopping test can pass), however slow the second
# process that meets it is to start on a loaded machine (with 40 iterations the first one finished
# in 5 s, and a second run started under a load of 8 found the folder free)
NO_STOPPING_TEST = ["--set", "optimizer.tol_change=1e-300", "--set", "optimizer.tol_objective=1e-300",
                    "--set", "optimizer.stall_iterations=100"]
UNTIL_STOPPED = [*NO_STOPPING_TEST, "--set", "optimizer.max_iter=10000"]


def test_a_second_run_into_a_busy_folder_exits_2_naming_the_first(tmp_path):
    import json
    import signal
    first = subprocess.Popen([sys.executable, "-m", "tofsi.cli", "optimize", OPT, "--output", "out", *TINY_OPT,
                              *UNTIL_STOPPED, "-q"], cwd=tmp_path,
                             stderr=subprocess.PIPE, text=True)
    try:
        wait_for(tmp_path / "out" / ".tofsi.lock")
        second = tofsi(["optimize", OPT, "--output", "out", *TINY_OPT, "--overwrite"], tmp_path)
        lines = second.stderr.strip().splitlines()
        assert second.returncode == 2 and len(lines) == 1, second.stderr
        assert f"in use by tofsi optimize (pid {first.pid} on host" in lines[0]
        wait_for(tmp_path / "out" / "run.json")    # a run stopped before its first write leaves no record
    finally:
        first.send_signal(signal.SIGTERM)
        status = first.wait()
    assert status == 143, first.stderr.read()
    assert not (tmp_path / "out" / ".tofsi.lock").exists()
    assert json.loads((tmp_path / "out" / "run.json").read_text())["status"] == "terminated"


def test_the_lock_of_a_killed_run_is_taken_over(tmp_path):
    """SIGKILL leaves the lock file; its record lock died with the process, so the next run
    (here --resume) takes it over and says whose it was."""
    import signal
    first = subprocess.Popen([sys.executable, "-m", "tofsi.cli", "optimize", OPT, "--output", "out", *TINY_OPT,
                              *UNTIL_STOPPED, "-q"], cwd=tmp_path)
    wait_for(tmp_path / "out" / "checkpoint.npz")
    first.send_signal(signal.SIGKILL)
    first.wait()
    assert (tmp_path / "out" / ".tofsi.lock").exists()
    again = tofsi(["optimize", OPT, "--output", "out", *TINY_OPT, *NO_STOPPING_TEST, "--set", "optimizer.max_iter=3",
                   "--resume"], tmp_path)
    assert again.returncode == 0, again.stderr
    assert f"took over the lock of tofsi optimize (pid {first.pid}" in again.stderr
    assert not (tmp_path / "out" / ".tofsi.lock").exists()


def test_one_process_cannot_lock_a_folder_twice(tmp_path):
    from tofsi.core.errors import InputError
    from tofsi.runs.run_folder import RunFolder
    first = RunFolder(tmp_path / "o", program="a").check()
    with pytest.raises(InputError, match="in this process"):
        RunFolder(tmp_path / "o", program="b").check()
    first.finish(0)
    RunFolder(tmp_path / "o", program="b").check().finish(0)
    assert not (tmp_path / "o").exists()                  # nothing written: the folder goes again


def test_a_run_refused_while_the_owner_writes_its_record_names_the_owner(tmp_path):
    """The owner takes the record lock, then writes its name: a run refused in between said
    "another run (starting)" (seen once when two runs started at once under load). It now reads
    the record again until it is written. The owner here (another process) takes the lock on a
    file it then moves into place, and names itself 0.5 s later."""
    import textwrap
    from tofsi.core.errors import InputError
    from tofsi.runs.folder_lock import LOCK_NAME, FolderLock
    folder = tmp_path / "o"
    folder.mkdir()
    owner = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import fcntl, json, os, time
        fd = os.open({str(folder / 'tmp')!r}, os.O_CREAT | os.O_RDWR)
        fcntl.lockf(fd, fcntl.LOCK_EX)
        os.rename({str(folder / 'tmp')!r}, {str(folder / LOCK_NAME)!r})
        time.sleep(0.5)
        os.write(fd, json.dumps({{"pid": os.getpid(), "host": "h", "program": "tofsi optimize",
                                  "started": "now"}}).encode())
        time.sleep(30)
    """)])
    try:
        wait_for(folder / LOCK_NAME)
        with pytest.raises(InputError, match=f"in use by tofsi optimize \\(pid {owner.pid} on host h"):
            FolderLock(folder, "tofsi solve").acquire()
    finally:
        owner.kill()
        owner.wait()


# ---- issue 25: sweeps and options refused before computing --------------------------------------
@pytest.mark.parametrize("sweep,says", [("mover.layers[0]=nan:1:0.1", "not a finite number"),
                                        ("mover.layers[0]=1:inf:1", "not a finite number"),
                                        ("mover.layers[0]=1:1e9:1", "at most 100000"),
                                        ("mover.yeoh.A20=1e-300:1e300:*1.0000001", "at most 100000")])
def test_non_finite_and_oversized_sweeps_are_refused_at_once(sweep, says, cli, tmp_path):
    """nan gave a traceback; 1:1e9:1 made a 10^9-value array for 40 s before refusing."""
    import time
    t0 = time.perf_counter()
    run = cli("study", FOIL, "--output", "out", "--sweep", sweep, cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1 and "--sweep" in lines[0] and says in lines[0], run.stderr
    assert time.perf_counter() - t0 < 20 and os.listdir(tmp_path) == []


def test_a_grid_of_too_many_points_is_refused_before_it_is_made():
    from tofsi.core.errors import InputError
    from tofsi.optimization.study import Sweep, points
    sweeps = [Sweep(f"k{i}", tuple(range(1000))) for i in range(3)]          # 10^9 points
    with pytest.raises(InputError, match="1,000,000,000 points"):
        points(sweeps)
    assert len(points(sweeps[:1])) == 1000


@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_max_memory_must_be_a_positive_number_of_gb(value, cli, tmp_path):
    """nan was accepted; -1 was refused naming mesh.h_min."""
    run = cli("move", FOIL, "--output", "out", "--max-memory", value, cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1 and lines[0].startswith("tofsi: error: --max-memory")
    assert os.listdir(tmp_path) == []


def test_resume_and_overwrite_together_are_refused(cli, tmp_path):
    run = cli("optimize", OPT, "--output", "out", "--resume", "--overwrite", cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1 and "--resume" in lines[0] and "--overwrite" in lines[0]


@pytest.mark.acceptance
@pytest.mark.parametrize("example", ["mesh_motion_study.py", "tuning_band_study.py"])
def test_the_study_examples_run_without_arguments(example, tmp_path):
    """They exited 2 asking for a study name; without one they run their small default."""
    from conftest import SCENES
    run = subprocess.run([sys.executable, str(SCENES.parent / example)], capture_output=True, text=True,
                         cwd=tmp_path, env={**os.environ, "TOFSI_EXAMPLE_SMALL": "1"})
    assert run.returncode == 0, run.stderr
    made = {"mesh_motion_study.py": "results/mesh_motion_study/graded/triangulation.csv",
            "tuning_band_study.py": "results/tuning_band_study/band.csv"}[example]
    assert (tmp_path / made).is_file()


def test_a_scene_file_of_megabytes_is_announced_before_it_is_read(cli, tmp_path):
    """A 10 MB scene read for minutes without a word; now a line says what is being read."""
    scene = tmp_path / "big.toml"
    scene.write_text(open(FOIL).read() + ("# padding\n" * 120_000))             # 1.2 MB
    run = cli("mesh", scene, "--output", "out", "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1",
              cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.stderr.splitlines()[0] == f"reading the scene file {scene} (1 MB) ..."
    quiet = cli("mesh", scene, "--output", "out2", "-q", "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1",
                cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == ""


def test_one_list_entry_is_set_by_its_index():
    """--set KEY[i]=V said "unknown key"; it replaces entry i of the scene's list."""
    import tofsi as toolkit
    both = toolkit.load_scene(FOIL, ["mover.layers=[1.5, 2.5]", "mover.layers[1]=3"])
    assert both.mover.layers == (1.5, 3.0)
    moved = toolkit.load_scene(FOIL, ["geometry.solids[0][1]=1.3"])
    assert moved.geometry.solids == ((0.75, 1.3, 0.475, 0.525),)
    assert moved == toolkit.load_scene(FOIL, ["geometry.solids=[[0.75, 1.3, 0.475, 0.525]]"])


def test_thousands_of_rectangles_are_refused_before_the_mesh_is_graded(cli, tmp_path):
    """A 10 MB scene of 350k solids graded for minutes without a word (5000 solids would have
    taken hours): the grid lines their edges need are counted first."""
    import random
    import re
    import time
    rnd = random.Random(1)
    rows = []
    for _ in range(5000):
        x, y = rnd.uniform(0.1, 1.8), rnd.uniform(0.1, 0.8)
        rows.append(f"[{x:.5f}, {x + 0.01:.5f}, {y:.5f}, {y + 0.01:.5f}]")
    scene = tmp_path / "many.toml"
    scene.write_text(re.sub(r"^solids = .*$", "solids = [" + ", ".join(rows) + "]", open(FOIL).read(),
                            flags=re.M))
    t0 = time.perf_counter()
    run = cli("mesh", scene, "--output", "out", cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "geometry.solids" in lines[0] and "5000 rectangles" in lines[0] and "mesh.max_elements" in lines[0]
    assert time.perf_counter() - t0 < 30 and not (tmp_path / "out").exists()


# ---- issue 25: diagnostics that point at the failing element ------------------------------------
FSI = str(scene_path("beam_in_channel_optimization_fsi"))


def test_a_failed_two_way_solve_names_the_element_the_predictor_inverts(tmp_path):
    """solve --stage last at E = 5 blamed "worst element 0 (skewness 1)": a perfect corner
    element of the undeformed mesh. The message now names the element the mover's predictor
    inverts; checked against the mesh: its number's reference centre is the one printed, and
    it lies at the beam (within two elements of the solid), where the flow pushes."""
    import json
    import re
    import tofsi as toolkit
    from tofsi.mesh.channel import build_mesh
    from tofsi.mesh.structured import SOLID
    mesh_args = ["mesh.h_min=0.05", "mesh.h_max=0.05", "structure.youngs_modulus=5"]
    run = tofsi(["solve", FSI, "--stage", "last", "--output", "out", *[a for o in mesh_args for a in ("--set", o)]],
                tmp_path)
    assert run.returncode == 3, run.stderr
    line = run.stderr.strip().splitlines()[-1]
    assert "skewness 1)" not in line and "worst element 0 " not in line
    found = re.search(r"inverts element (\d+) at \(([-\d.e]+), ([-\d.e]+)\) m \(skewness (-[\d.e]+)\)", line)
    assert found, line
    k, x, y = int(found[1]), float(found[2]), float(found[3])
    mesh = build_mesh(*(lambda s: (s.geometry, s.mesh))(toolkit.load_scene(FSI, mesh_args)))
    np.testing.assert_allclose(mesh.centroids[k], [x, y], rtol=5e-3, atol=1e-12)
    solid = mesh.centroids[mesh.region == SOLID]
    assert np.min(np.linalg.norm(solid - mesh.centroids[k], axis=1)) < 2 * 0.05
    diagnostic = json.loads((tmp_path / "out" / "diagnostic.json").read_text())
    assert diagnostic["broken_element"]["element"] == k and diagnostic["broken_element"]["skewness"] < 0


def test_a_newton_that_stops_on_a_valid_mesh_says_no_element_failed(tmp_path):
    """A Yeoh move out of Newton iterations: no element is blamed; the message says none
    inverted."""
    import json
    run = tofsi(["move", FOIL, "--output", "out", "--set", "deformation.mode=rotation", "--set",
                 "mover.yeoh.max_newton=1", "--set", "mover.yeoh.max_cutbacks=0", "--set",
                 "mover.yeoh.increments=4"], tmp_path)
    assert run.returncode == 3, run.stderr
    line = run.stderr.strip().splitlines()[-1]
    assert "1 Newton iterations at load 0.25 did not reach the tolerance (no element inverted)" in line
    assert "worst element" not in line and "no load step was accepted" in line, line
    assert "broken_element" not in json.loads((tmp_path / "out" / "diagnostic.json").read_text())


def test_an_inverted_mesh_message_rounds_its_coordinates(tmp_path):
    """failed_mesh.png's title carried 16-digit coordinates ("at [1.2762882690614328, ...]")."""
    import re
    run = tofsi(["move", FOIL, "--output", "out", "--set", "mover.name=spring", "--set", "deformation.mode=rotation",
                 "--set", "deformation.rotation_deg=45", "--set", "mover.spring.increments=1",
                 "--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.1"], tmp_path)
    assert run.returncode == 3, run.stderr
    assert re.search(r"worst element \d+ \(skewness -?[\d.]+\) at \([\d.]+, [\d.]+\) m", run.stderr), run.stderr
    assert not re.search(r"\d\.\d{5,}", run.stderr.split("(diagnostic")[0])


def test_the_readme_exit_status_table_lists_every_status():
    """Every status the command line returns (run.json's status words, the errors' exit
    statuses) has a row in README's table, and the table has no other."""
    import re
    from pathlib import Path
    from tofsi.core import errors
    from tofsi.runs.run_folder import STATUS
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    rows = {int(m) for m in re.findall(r"^\| (\d+) \| ", readme, flags=re.M)}
    raised = {cls.exit_status for cls in (errors.InputError, errors.NumericalError, errors.WriteError)}
    assert rows == set(STATUS) and raised <= rows and {0, 1, 130, 143} <= rows


# ---- issue 35, item 1: no non-finite number is written as a result ------------------------------
def strict_json(path):
    """JSON that holds no NaN or infinity (Python's json would read them back silently)."""
    import json

    def refuse(constant):
        raise AssertionError(f"{path} holds {constant}")
    return json.loads(path.read_text(), parse_constant=refuse)


def assert_all_finite(folder):
    """Every result file of a run folder: JSON without NaN/Infinity, CSV without nan/inf cells,
    VTU arrays, design.npy and the checkpoint's arrays finite."""
    import csv
    import json
    import meshio
    for path in folder.iterdir():
        if path.suffix == ".json":
            strict_json(path)
        elif path.suffix == ".csv":
            cells = [c.lower() for row in csv.reader(path.open()) for c in row]
            assert not {"nan", "inf", "-inf"} & set(cells), path
        elif path.suffix == ".vtu":
            mesh = meshio.read(path)
            arrays = [mesh.points, *mesh.point_data.values(), *(v[0] for v in mesh.cell_data.values())]
            assert all(np.all(np.isfinite(a)) for a in arrays), path
        elif path.suffix == ".npy":
            assert np.all(np.isfinite(np.load(path))), path
        elif path.suffix == ".npz":
            with np.load(path) as data:
                for key in data.files:
                    if key == "meta":
                        json.loads(str(data["meta"]), parse_constant=lambda c, path=path: pytest.fail(f"{c} in {path}"))
                    else:
                        assert np.all(np.isfinite(data[key])), (path, key)


@pytest.mark.parametrize("scene,overrides", [
    (OPT, ["design.min_skewness=0.5"]),                                     # a one-way scene
    (FSI, ["design.min_skewness=0.5", 'design.coupling=["one-way"]']),      # a one-way schedule
])
def test_a_skewness_bound_where_no_stage_moves_the_mesh_is_refused(scene, overrides, cli, tmp_path):
    """Issue 35: exit 0 with NaN in history.csv (the bound's column) and in the VTU design
    arrays; the bound cannot apply without a two-way stage, so it is refused before computing."""
    run = cli("optimize", scene, "--output", tmp_path / "out", *[a for o in overrides for a in ("--set", o)])
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert lines[0].startswith("tofsi: error: design.min_skewness = 0.5") and "no stage" in lines[0]
    assert "two-way" in lines[0] and not (tmp_path / "out").exists()


def test_a_forced_non_finite_objective_is_a_numerical_failure_and_no_file_holds_it(cli, tmp_path, monkeypatch):
    """The compliance made NaN from the third evaluation on: exit 3 naming the quantity and the
    design iteration; the files of the iterations before it are complete and finite (the
    history's not-applicable columns blank, the design VTUs finite outside the design region)."""
    from tofsi.objectives.compliance import Compliance
    value, calls = Compliance.value, []

    def forced(self, model, state):
        calls.append(1)
        return float("nan") if len(calls) > 2 else value(self, model, state)
    monkeypatch.setattr(Compliance, "value", forced)
    run = cli("optimize", OPT, "--output", tmp_path / "out", *TINY_OPT, "--set", "optimizer.max_iter=6",
              "--set", "optimizer.max_failures=1", "--set", "optimizer.output_every=1")
    line = run.stderr.strip().splitlines()[-1]
    assert run.returncode == 3, run.stderr
    assert "design iteration 2" in line and "not finite: compliance (nan)" in line, line
    out = tmp_path / "out"
    assert [r["iteration"] for r in strict_json(out / "history.json")] == [0, 1]
    assert strict_json(out / "history.json")[0]["min_skewness"] is None
    assert (out / "design_0001.vtu").exists() and not (out / "result.json").exists()
    assert_all_finite(out)


def test_a_forced_non_finite_figure_of_a_solve_is_a_numerical_failure(cli, tmp_path, monkeypatch):
    """An infinite objective: exit 3 naming it; neither solve.json nor a VTU is written."""
    from tofsi.objectives.compliance import Compliance
    monkeypatch.setattr(Compliance, "value", lambda self, model, state: float("inf"))
    run = cli("solve", OPT, "--output", tmp_path / "out", *TINY_OPT)
    line = run.stderr.strip().splitlines()[-1]
    assert run.returncode == 3, run.stderr
    assert "solve: not finite: objective (inf)" in line and "no element failed" in line
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["diagnostic.json", "run.json"]
    assert_all_finite(tmp_path / "out")


def test_a_modulus_near_the_floating_point_limit_gives_finite_unphysical_figures(cli, tmp_path):
    """E = 1e-300 gave an infinite max_displacement (its norm overflowed) with exit 0 from
    optimize; the figures are now finite (4e304 m) and the state is flagged unphysical."""
    run = cli("solve", OPT, "--output", tmp_path / "out", "--set", "structure.youngs_modulus=1e-300", *TINY_OPT)
    assert run.returncode == 5, run.stderr
    figures = strict_json(tmp_path / "out" / "solve.json")["figures"]
    assert figures["physical"] is False and 1e303 < figures["max_displacement"] < 1e306
    assert_all_finite(tmp_path / "out")


def test_a_finished_optimization_writes_only_finite_numbers(cli, tmp_path):
    run = cli("optimize", OPT, "--output", tmp_path / "out", *TINY_OPT, "--set", "optimizer.max_iter=3")
    assert run.returncode == 0, run.stderr
    assert_all_finite(tmp_path / "out")
    history = strict_json(tmp_path / "out" / "history.json")
    assert all(h["min_skewness"] is None and h["skewness_constraint"] is None for h in history)
    assert strict_json(tmp_path / "out" / "result.json")["physical"] is True


# ---- issue 36, item 3: exit 0 only for a physical final ------------------------------------------
def test_an_optimization_ending_on_an_unphysical_state_exits_5(cli, tmp_path):
    """The FSI scene (E = 5 kPa) on a short coarse schedule ended one-way at 59 m of solid
    displacement with exit 0. Now exit 5: written, physical false with the reason, as solve."""
    args = ["optimize", FSI, *TINY_OPT, "--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.05",
            "--set", "optimizer.max_iter=6"]
    run = cli(*args, "--output", tmp_path / "out")
    assert run.returncode == 5, run.stderr
    result = strict_json(tmp_path / "out" / "result.json")
    assert result["physical"] is False and "exceeds the channel's length" in result["unphysical"]
    assert "no physical state" in run.stderr and "--allow-unphysical" in run.stderr
    assert strict_json(tmp_path / "out" / "run.json")["exit_status"] == 5
    accepted = cli(*args, "--output", tmp_path / "ok", "--allow-unphysical")
    assert accepted.returncode == 0 and "no physical state" in accepted.stderr


def test_physicality_covers_every_direction_and_the_channel_walls():
    """1.4 m of displacement in a 1 m high channel passed (the check took the longest side,
    2 m); every direction now: a component beyond the channel's size in it, a solid node moved
    out of the channel, a non-finite value. A physical displacement passes."""
    import tofsi as toolkit
    from tofsi.coupling.coupled import CoupledModel
    model = CoupledModel(toolkit.load_scene(OPT, ["mesh.h_min=0.1", "mesh.h_max=0.1"]))
    structure, mesh = model.structure, model.mesh
    rho = model.densities()                                    # the fixed wall x in [0.975, 1.025], y < 0.5
    u = np.zeros((mesh.n_nodes, 2))
    assert structure.displacement_beyond_channel(u, rho) == ""
    u[:, 1] = 1.4 * mesh.points[:, 1]                           # 1.4 m at the top, in y
    assert "1.4 m in y exceeds the channel's height (1 m)" in structure.displacement_beyond_channel(u, rho)
    u[:] = 0.0
    u[mesh.points[:, 1] > 0, 0] = 1.2                          # the wall (x <= 1.025) to x = 2.2: out
    assert "the solid leaves the channel" in structure.displacement_beyond_channel(u, rho)
    assert structure.displacement_beyond_channel(u) == ""       # without densities: no solid known
    u[:, 0] = 0.1 * mesh.points[:, 1]
    assert structure.displacement_beyond_channel(u, rho) == ""  # 5 cm at the wall's top: physical
    u[3, 1] = np.inf
    assert "not finite at 1 node" in structure.displacement_beyond_channel(u, rho)


# ---- issue 35, items 2 and 3; issue 36, item 4: no traceback from any entry point ---------------
def modules_with_main() -> set[str]:
    """Every ``tofsi.*`` module that defines a ``main`` (what ``python -m`` can run)."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    return {".".join(p.relative_to(root).with_suffix("").parts) for p in (root / "tofsi").rglob("*.py")
            if "\ndef main(" in p.read_text()}


def entry_points():
    """``(module, leading arguments)``: each tofsi subcommand, and every other module with a main."""
    from tofsi.cli import COMMANDS
    walk = {"tofsi.cli": [[c] for c in COMMANDS]}
    assert set(walk) == modules_with_main(), "add the new module's arguments to the walk"
    return [(m, lead) for m, leads in walk.items() for lead in leads]


def scene_for(lead) -> str:
    return FOIL if lead and lead[0] in ("mesh", "move", "tune", "study") else OPT


def run_main(module, argv, capsys):
    import importlib
    capsys.readouterr()
    status = importlib.import_module(module).main([str(a) for a in argv])
    return status, capsys.readouterr().err


BAD_ARGUMENTS = {"missing scene": lambda lead: ["nowhere.toml"],
                 "bad --set": lambda lead: [scene_for(lead), "--set", "mesh.h_mni=0.1"],
                 "nested --set": lambda lead: [scene_for(lead), "--set", "mover.layers=" + "[" * 3000 + "]" * 3000]}


@pytest.mark.parametrize("case", sorted(BAD_ARGUMENTS))
@pytest.mark.parametrize("module,lead", entry_points(), ids=lambda v: v if isinstance(v, str) else " ".join(v))
def test_every_entry_point_answers_bad_input_in_one_line(module, lead, case, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    extra = ["--sweep", "mover.layers[0]=1:2:1"] if lead == ["study"] else []
    status, err = run_main(module, [*lead, *BAD_ARGUMENTS[case](lead), *extra, "--output", "out"], capsys)
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert {"missing scene": "no such file", "bad --set": "mesh.h_mni",
            "nested --set": "nested more than 16"}[case] in lines[0]
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("module,lead", [e for e in entry_points() if e[1] != ["mesh"]],
                         ids=lambda v: v if isinstance(v, str) else " ".join(v))
def test_every_entry_point_names_a_missing_optional_package_with_its_install_hint(module, lead, capsys, tmp_path,
                                                                                  monkeypatch):
    """petsc4py made unimportable (the distributed driver needs it; the others for the petsc
    backend): one line, exit 2, the install hint. (``tofsi mesh`` solves nothing.)"""
    import sys
    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, "petsc4py", None)
    extra = ["--sweep", "mover.layers[0]=1:2:1"] if lead == ["study"] else []
    status, err = run_main(module, [*lead, scene_for(lead) if lead else str(scene_path("double_pipe")),
                                    "--set", "solver.linear_solver=petsc", *extra, "--output", "out"], capsys)
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "petsc4py does not import" in lines[0] and "python3-petsc4py-real" in lines[0]
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("command,overrides,says", [
    ("mesh", ["name=\udcff"], "undecodable byte (not UTF-8), the byte 0xff"),        # UnicodeEncodeError
    ("mesh", ["name=a\u200bb"], "invisible character, U+200B ZERO WIDTH SPACE"),      # accepted before
    ("mesh", ["name=a\u2028b"], "line separator"),
    ("mesh", ["--output", "t\udcff"], "undecodable byte"),
    ("mesh", ["--output", "a\u200bb/c"], "invisible character"),
    ("check-gradients", ["--seed", "-1"], "--seed"),                                    # ValueError
    ("solve", ["solver.linear_solver=iterative", "fluid.element=q1q1"], "fluid.element"),   # KeyError
    ("solve", ["fluid.alpha_max=1e300"], "fluid.alpha_max"),                            # ValueError
    ("optimize", ["optimizer.max_iter=100000000"], "optimizer.max_iter"),              # 1.2 GB to refuse
    ("optimize", ["optimizer.max_iter=1000000000"], "optimizer.max_iter"),
    ("optimize", ["design.stage_iterations=100000000"], "design.stage_iterations"),
    ("solve", ["coupled.min_load_step=1e-300"], "coupled.min_load_step"),              # ran for hours
])
def test_limits_and_names_refused_in_one_line(command, overrides, says, cli, tmp_path):
    """Issues 35/36: tracebacks (undecodable names, negative seeds, q1q1 on the iterative path,
    alpha_max 1e300), invisible names accepted, resource limits found late or never."""
    import time
    args = [command, FOIL if command == "mesh" else OPT]
    extra = list(overrides)
    while extra:
        item = extra.pop(0)
        args += [item, extra.pop(0)] if item.startswith("--") else ["--set", item]
    if "--output" not in args:
        args += ["--output", "out"]
    t0 = time.perf_counter()
    run = cli(*args, cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert says in lines[0] and time.perf_counter() - t0 < 30
    assert os.listdir(tmp_path) == []


def test_a_deeply_nested_scene_file_is_refused(cli, tmp_path):
    """A scene nested thousands deep ended in RecursionError (tomllib), hundreds deep in the
    copy of the scene."""
    (tmp_path / "deep.toml").write_text("name = 'x'\nx = " + "[" * 3000 + "]" * 3000 + "\n")
    (tmp_path / "deeper.toml").write_text("name = 'x'\n[a]\nx = " + "[" * 400 + "]" * 400 + "\n")
    for scene, says in (("deep.toml", "scene = "), ("deeper.toml", "a.x[0][0]")):
        run = cli("mesh", tmp_path / scene, "--output", tmp_path / "out")
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(lines) == 1 and says in lines[0] and "nested more than 16" in lines[0]
