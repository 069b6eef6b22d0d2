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
