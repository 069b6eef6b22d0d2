"""Output folders: checked before any computation, never two runs mixed, run.json provenance."""

import errno
import json
import os
import subprocess
import tomllib

import numpy as np
import pytest

import tofsi
from tofsi.core.errors import InputError
from tofsi.runs.provenance import scene_tables
from tofsi.runs.run_folder import RunFolder, check_writable
from tofsi.scene.scene import scene_from_dict

from conftest import scene_path

FOIL = str(scene_path("foil_in_channel"))
OPT = str(scene_path("beam_in_channel_optimization"))
COARSE_FOIL = ["--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.1"]
SPRING_45 = [*COARSE_FOIL, "--set", "mover.name=spring", "--set", "deformation.mode=rotation",
             "--set", "deformation.rotation_deg=45"]          # inverts with 1 increment, not with 2
TINY_OPT = ["--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1", "--set", "design.filter_radius=0.15",
            "--set", "design.stage_iterations=2"]


def snapshot(folder):
    return {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in folder.iterdir()}


# ---- item 1: the output folder is checked before any computation ------------------------------
@pytest.mark.parametrize("where", ["existing file", "under a file", "/dev/null", "/proc/tofsi_out",
                                   "/sys/tofsi_out"])
def test_an_unwritable_output_exits_2_before_solving(cli, where, tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    output = {"existing file": "notes.txt", "under a file": "notes.txt/out"}.get(where, where)
    run = cli("solve", OPT, "--output", output, *TINY_OPT, cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr      # no "solving ..." line: no solve
    assert "--output" in lines[0] and "Traceback" not in run.stderr
    assert os.listdir(tmp_path) == ["notes.txt"] and (tmp_path / "notes.txt").read_text() == "mine"


def test_a_read_only_filesystem_is_refused(tmp_path, monkeypatch):
    """Root passes permission checks, a read-only mount does not: the check writes a probe."""
    import tempfile

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")
    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    with pytest.raises(InputError, match="--output.*Read-only file system"):
        check_writable(tmp_path / "out")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_folder_without_write_permission_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    with pytest.raises(InputError, match="cannot write"):
        check_writable(locked / "out")


def test_the_probe_leaves_nothing_behind(tmp_path):
    check_writable(tmp_path / "a" / "b")
    assert os.listdir(tmp_path) == []


# ---- item 2: runs never mix ---------------------------------------------------------------------
def test_a_fresh_optimize_refuses_a_folder_of_another_run_and_overwrite_replaces_it(cli, tmp_path):
    first = cli("optimize", OPT, "--output", "out", *TINY_OPT, "--set", "optimizer.max_iter=6",
                      "--set", "optimizer.output_every=5", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    out = tmp_path / "out"
    (out / "my_notes.txt").write_text("keep me")
    assert (out / "design_0005.vtu").is_file()
    before = snapshot(out)

    refused = cli("optimize", OPT, "--output", "out", *TINY_OPT, "--set", "optimizer.max_iter=3",
                        cwd=tmp_path)
    lines = refused.stderr.strip().splitlines()
    assert refused.returncode == 2 and len(lines) == 1 and "--overwrite" in lines[0], refused.stderr
    assert snapshot(out) == before                                  # untouched, bit for bit

    again = cli("optimize", OPT, "--output", "out", *TINY_OPT, "--set", "optimizer.max_iter=3",
                      "--set", "optimizer.output_every=5", "--overwrite", cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    names = set(os.listdir(out))
    assert "design_0005.vtu" not in names and "design_0005.png" not in names   # the old run's
    assert (out / "my_notes.txt").read_text() == "keep me"                     # not tofsi's: kept
    history = json.loads((out / "history.json").read_text())
    assert len(history) == 3
    record = json.loads((out / "run.json").read_text())
    assert "my_notes.txt" not in record["files"] and "design_0003.vtu" not in names


def test_a_failed_move_never_sits_beside_an_earlier_success(cli, tmp_path):
    ok = cli("move", FOIL, "--output", "out", *SPRING_45, "--set", "mover.spring.increments=2",
                   cwd=tmp_path)
    assert ok.returncode == 0 and (tmp_path / "out" / "move.json").is_file(), ok.stderr
    failed = cli("move", FOIL, "--output", "out", *SPRING_45, "--set", "mover.spring.increments=1",
                       "--overwrite", cwd=tmp_path)
    assert failed.returncode == 3, failed.stderr
    names = set(os.listdir(tmp_path / "out"))
    assert "move.json" not in names and "moved_mesh.vtu" not in names
    assert {"diagnostic.json", "failed_mesh.png", "run.json"} <= names
    record = json.loads((tmp_path / "out" / "run.json").read_text())
    assert record["exit_status"] == 3 and record["status"] == "numerical failure"


def test_examples_replace_their_own_run_but_not_another(tmp_path):
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(InputError, match="--overwrite"):
        RunFolder(tmp_path, program="examples/x.py", replaces_own=True).check()
    own = tmp_path / "own"
    folder = RunFolder(own, program="examples/x.py", replaces_own=True).check()
    folder.begin({"program": "examples/x.py"})
    (own / "design_0009.png").write_text("old picture")
    folder.finish(0)
    again = RunFolder(own, program="examples/x.py", replaces_own=True).check()     # its own: fine
    again.begin({"program": "examples/x.py"})
    assert [n for n in os.listdir(own) if not n.startswith(".")] == ["run.json"]   # lock, reserve: hidden
    again.finish(0)
    assert os.listdir(own) == ["run.json"]
    with pytest.raises(InputError, match="examples/x.py"):
        RunFolder(own, program="tofsi optimize").check()


# ---- item 4: provenance -------------------------------------------------------------------------
def test_run_json_holds_the_effective_scene_and_the_run(cli, tmp_path):
    run = cli("optimize", OPT, "--output", "out", *TINY_OPT, "--set", "optimizer.max_iter=3",
                    "--set", "design.volume_fraction=0.3", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    record = json.loads((tmp_path / "out" / "run.json").read_text())
    expected = tofsi.load_scene(OPT, [a for a in TINY_OPT if a != "--set"]
                                + ["optimizer.max_iter=3", "design.volume_fraction=0.3"])
    assert scene_from_dict(tomllib.loads(record["scene"]), source=expected.source) == expected
    assert "design.volume_fraction=0.3" in record["overrides"]
    assert record["command_line"][:2] == ["tofsi", "optimize"] and "--output" in record["command_line"]
    assert record["tofsi_version"] == tofsi.__version__
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=os.path.dirname(tofsi.__file__)).stdout.strip()
    assert record["git_commit"] == (commit or None)
    assert record["started"] <= record["finished"] and record["exit_status"] == 0
    assert record["stop_reason"] == "max_iter" and record["status"] == "finished"
    assert set(record["files"]) == set(os.listdir(tmp_path / "out"))
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["stop_reason"] == "max_iter" and result["iterations"] == 3


def test_move_and_solve_json_carry_the_settings_that_define_the_result(cli, tmp_path):
    run = cli("move", FOIL, "--output", "m", *COARSE_FOIL, "--set", "deformation.mode=rotation",
                    "--set", "deformation.rotation_deg=12.5", "--set", "mover.name=linear", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    move = json.loads((tmp_path / "m" / "move.json").read_text())["settings"]
    assert move["deformation"]["mode"] == "rotation" and move["deformation"]["rotation_deg"] == 12.5
    assert move["mover"]["name"] == "linear" and "poisson_ratio" in move["mover"]["params"]
    assert move["mesh"]["h_min"] == 0.05

    run = cli("solve", OPT, "--output", "s", *TINY_OPT, "--set", "fluid.viscosity=2", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    solve = json.loads((tmp_path / "s" / "solve.json").read_text())["settings"]
    assert solve["fluid"]["viscosity"] == 2.0 and solve["effects"]["fluid"] == "navier-stokes"
    assert solve["design"] == "uniform" and solve["stage"] == 0 and solve["beta"] == 1.0


def test_the_effective_scene_round_trips_through_toml_for_every_shipped_scene(shipped_scene):
    from tofsi.runs.provenance import scene_toml
    again = scene_from_dict(tomllib.loads(scene_toml(shipped_scene)), source=shipped_scene.source)
    assert again == shipped_scene and scene_tables(again) == scene_tables(shipped_scene)


def test_an_interrupted_run_records_its_stop(tmp_path):
    folder = RunFolder(tmp_path / "o", program="tofsi optimize").check()
    folder.begin({"program": "tofsi optimize", "status": "running"})
    np.save(tmp_path / "o" / "design.npy", np.zeros(3))
    folder.finish(130, stop_reason="interrupted")
    record = json.loads((tmp_path / "o" / "run.json").read_text())
    assert record["status"] == "interrupted" and record["stop_reason"] == "interrupted"
    assert record["files"] == ["design.npy", "run.json"]
