"""Two-way optimization runs: the moved mesh's quality is part of the record, and a mover that
cannot follow the structure stops the run with exit 3 naming the iteration and the element,
after the earlier iterations are checkpointed."""

import json
import re

import numpy as np

from conftest import scene_path

SMALL = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.2", "design.beta=[1.0, 2.0]",
         'design.coupling=["one-way", "two-way"]', "design.stage_iterations=2", "optimizer.max_iter=4"]


def optimize(cli, tmp_path, *overrides):
    args = [a for o in (*SMALL, *overrides) for a in ("--set", o)]
    return cli("optimize", str(scene_path("beam_in_channel_optimization_fsi")), "--output",
               str(tmp_path / "out"), *args)


def test_two_way_iterations_record_the_moved_mesh_quality(cli, tmp_path):
    run = optimize(cli, tmp_path, "structure.youngs_modulus=1e6")
    assert run.returncode == 0, run.stderr
    rows = json.loads((tmp_path / "out" / "history.json").read_text())
    assert [r["coupling"] for r in rows] == ["one-way", "one-way", "two-way", "two-way"]
    assert all(r["min_skewness"] is None for r in rows[:2])           # the mesh did not move (NaN: null)
    for r in rows[2:]:
        assert 0.0 < r["min_skewness"] < 1.0 and r["min_area_change"] < 1.0 < r["max_area_change"]
    import meshio
    final = meshio.read(tmp_path / "out" / "design_final.vtu")       # the final design's moved mesh
    assert 0.0 < np.min(final.cell_data["skewness"][0]) < 1.0
    assert (tmp_path / "out" / "convergence.png").is_file()


def test_a_mover_that_cannot_follow_stops_the_run_naming_the_iteration_and_element(cli, tmp_path):
    run = optimize(cli, tmp_path, "structure.youngs_modulus=1.0")      # the structure moves metres
    assert run.returncode == 3
    line = [ln for ln in run.stderr.splitlines() if "numerical failure" in ln][0]
    assert "design iteration 2" in line and "mover" in line
    assert re.search(r"inverts element \d+ at \([\d.]+, [\d.]+\) m", line), line     # the one that failed
    rows = json.loads((tmp_path / "out" / "history.json").read_text())
    assert len(rows) == 2                                              # checkpointed before it
    assert (tmp_path / "out" / "checkpoint.npz").is_file()
