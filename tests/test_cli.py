"""The command line: figures on --json, exit codes, outputs only where asked."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import ALL_SCENES, load, scene_path
from tofsi.mesh.channel import build_mesh


def tofsi(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "tofsi.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize("name", ALL_SCENES)
def test_mesh_json_reports_node_and_element_counts(name, tmp_path):
    run = tofsi("mesh", scene_path(name), "--output", tmp_path, "--json")
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    scene = load(name)
    mesh = build_mesh(scene.geometry, scene.mesh)
    assert figures["n_nodes"] == mesh.n_nodes == (mesh.nx + 1) * (mesh.ny + 1)
    assert figures["n_elements"] == mesh.n_elements == mesh.nx * mesh.ny
    assert sorted(os.listdir(tmp_path)) == ["mesh.png", "mesh.vtu", "run.json"]


@pytest.mark.parametrize("override,key", [
    ("mesh.h_mni=0.1", "mesh.h_mni"), ("mesh.h_min=-1", "mesh.h_min"),
    ("mesh.h_min=nan", "mesh.h_min"), ("mover.name=sprung", "mover.name"),
])
def test_malformed_scene_exits_2_with_one_line_naming_the_key(override, key, tmp_path):
    out = tmp_path / "out"
    run = tofsi("mesh", scene_path("foil_in_channel"), "--set", override, "--output", out)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in run.stderr
    assert not out.exists()


def test_missing_scene_file_exits_2(tmp_path):
    run = tofsi("mesh", tmp_path / "missing.toml")
    assert run.returncode == 2 and "no such file" in run.stderr


def test_unknown_option_exits_2_in_one_line():
    run = tofsi("mesh", scene_path("foil_in_channel"), "--frobnicate")
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1


def test_default_output_is_results_scene_name_under_the_working_directory(tmp_path):
    run = tofsi("mesh", scene_path("foil_in_channel"), cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "results" / "foil_in_channel" / "mesh.vtu").is_file()


def test_console_script_is_installed():
    exe = shutil.which("tofsi") or os.path.join(os.path.dirname(sys.executable), "tofsi")
    run = subprocess.run([exe, "--help"], capture_output=True, text=True)
    assert run.returncode == 0 and "mesh" in run.stdout and "move" in run.stdout


def test_mesh_vtu_is_readable_by_an_independent_reader(tmp_path):
    pv = pytest.importorskip("pyvista")
    assert tofsi("mesh", scene_path("beam_in_channel"), "--output", tmp_path).returncode == 0
    grid = pv.read(tmp_path / "mesh.vtu")
    scene = load("beam_in_channel")
    mesh = build_mesh(scene.geometry, scene.mesh)
    assert grid.n_points == mesh.n_nodes and grid.n_cells == mesh.n_elements
    np.testing.assert_array_equal(np.asarray(grid.cell_data["region"]), mesh.region)
    area = np.asarray(grid.compute_cell_sizes()["Area"])
    np.testing.assert_allclose(area, np.asarray(grid.cell_data["area"]), rtol=1e-12)
