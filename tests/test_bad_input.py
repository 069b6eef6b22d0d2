"""Malformed scenes and command lines: status 2, one line naming the key, nothing written."""

import os
import subprocess
import sys

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
]


def tofsi(args, cwd):
    return subprocess.run([sys.executable, "-m", "tofsi.cli", *args], capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize("command,scene,overrides,key", CASES, ids=[c[3] + ":" + " ".join(c[2]) for c in CASES])
def test_bad_values_exit_2_naming_the_key_and_write_nothing(command, scene, overrides, key, tmp_path):
    args = [command, scene, "--output", "out"]
    extra = list(overrides)
    while extra:
        item = extra.pop(0)
        args += [item, extra.pop(0)] if item.startswith("--") else ["--set", item]
    run = tofsi(args, tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2, run.stderr
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in run.stderr
    assert os.listdir(tmp_path) == []                                  # nothing partial


@pytest.mark.parametrize("kind", ["missing", "directory", "not toml", "binary"])
def test_unreadable_or_missing_scene_files_exit_2(kind, tmp_path):
    path = tmp_path / "scene.toml"
    if kind == "directory":
        path.mkdir()
    elif kind == "not toml":
        path.write_text("name = 'x'\n[mesh\nh_min = 1\n")
    elif kind == "binary":
        path.write_bytes(b"\xff\xfe\x00garbage\x00")
    run = tofsi(["mesh", str(path), "--output", str(tmp_path / "out")], tmp_path)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1
    assert "scene" in run.stderr and not (tmp_path / "out").exists()


@pytest.mark.parametrize("args", [["mesh"], ["nonsense", FOIL], ["mesh", FOIL, "--set"],
                                  ["mesh", FOIL, "--set", "no_equals_sign"], ["study", FOIL, "--jobs", "x"]])
def test_malformed_command_lines_exit_2_in_one_line(args, tmp_path):
    run = tofsi(args, tmp_path)
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


@pytest.mark.parametrize("kind,says", [("outside [0, 1]", "not clipped"), ("text", "not a NumPy .npy file"),
                                       ("wrong size", "needs"), ("pickle", "not a NumPy .npy file"),
                                       ("directory", "is a directory")])
def test_a_bad_saved_design_exits_2_with_a_plain_message(kind, says, tmp_path):
    """design.initial values outside [0, 1] were clipped silently; a text file got numpy's
    advice about pickles. Now: one line naming design.initial, saying what is wrong."""
    import tofsi as toolkit
    n = toolkit.Problem(toolkit.load_scene(OPT, ["mesh.h_min=0.1", "mesh.h_max=0.1"])).n_design
    write_design(tmp_path / "design.npy", kind, n)
    before = sorted(os.listdir(tmp_path))
    run = tofsi(["optimize", OPT, "--output", "out", "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1",
                     "--set", "design.initial=design.npy"], tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "design.initial" in lines[0] and says in lines[0] and "allow_pickle" not in lines[0]
    assert sorted(os.listdir(tmp_path)) == before


def test_a_scene_with_a_byte_order_mark_is_read(tmp_path):
    scene = tmp_path / "bom.toml"
    scene.write_bytes(b"\xef\xbb\xbf" + open(FOIL, "rb").read())
    run = tofsi(["mesh", str(scene), "--output", "out", "--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.1"],
                tmp_path)
    assert run.returncode == 0, run.stderr


def test_a_directory_given_as_the_scene_says_so(tmp_path):
    (tmp_path / "scenes").mkdir()
    run = tofsi(["mesh", "scenes", "--output", "out"], tmp_path)
    assert run.returncode == 2 and "is a directory" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_a_thin_solid_is_accepted_with_a_warning(tmp_path):
    run = tofsi(["mesh", FOIL, "--output", "out", "--set", "geometry.solids=[[0.75, 1.25, 0.5, 0.5000001]]",
                 "--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.1"], tmp_path)
    assert run.returncode == 0, run.stderr
    assert "WARNING" in run.stderr and "geometry.solids[0]" in run.stderr and "thinner" in run.stderr


def test_overlapping_solids_merge_into_their_union():
    """Two overlapping rectangles mesh as their union: the solid area is the union's, 0.7 x 0.2
    (the overlap counted once), and the result equals the single-rectangle scene's."""
    import numpy as np
    import tofsi as toolkit
    from tofsi.channel import build_mesh
    from tofsi.mesh import SOLID
    from tofsi.quality import signed_area

    def solid_area(solids):
        scene = toolkit.load_scene(FOIL, [f"geometry.solids={solids}", "mesh.h_min=0.025", "mesh.h_max=0.05"])
        mesh = build_mesh(scene.geometry, scene.mesh)
        return signed_area(mesh.points, mesh.quads[mesh.region == SOLID]).sum()
    assert solid_area("[[0.5, 1.0, 0.4, 0.6], [0.8, 1.2, 0.4, 0.6]]") == pytest.approx(0.7 * 0.2, rel=1e-12)
    assert solid_area("[[0.5, 1.2, 0.4, 0.6]]") == pytest.approx(0.7 * 0.2, rel=1e-12)
    assert np.isclose(solid_area("[[0.5, 1.0, 0.4, 0.6], [0.8, 1.2, 0.5, 0.7]]"), 0.1 + 0.08 - 0.02)


@pytest.mark.parametrize("args", [["optimize", OPT, "--set", "design.beta=[]"], ["nonsense", FOIL]])
def test_json_errors_on_stdout(args, tmp_path):
    """--json on exit 2 prints {"error": ...} on stdout (usage errors too)."""
    import json
    run = tofsi([*args, "--json", "--output", "out"], tmp_path)
    assert run.returncode == 2
    payload = json.loads(run.stdout)
    assert payload["exit_status"] == 2 and payload["error"] in run.stderr
