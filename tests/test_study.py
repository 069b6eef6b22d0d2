"""Parametric studies: sweep parsing, grids, list-entry sweeps, and ``tofsi study``."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from tofsi.core.errors import InputError
from tofsi.runs.output import read_csv, write_csv
from tofsi.optimization.study import Sweep, best, overrides_for, parse_sweep, points

from conftest import scene_path


def test_linear_range_includes_its_end():
    s = parse_sweep("mover.layers[0]=1:6:0.5")
    assert s.key == "mover.layers[0]"
    np.testing.assert_allclose(s.values, np.arange(1, 6.01, 0.5))


def test_geometric_range():
    assert parse_sweep("mover.yeoh.A20=1e-1:1e5:*10").values == pytest.approx([10.0**k for k in range(-1, 6)])


def test_value_lists_are_toml_or_bare_words():
    assert parse_sweep("mover.name=spring,yeoh").values == ("spring", "yeoh")
    assert parse_sweep("mover.spring.increments=5,10").values == (5, 10)


@pytest.mark.parametrize("text", ["mover.name", "a=1:2", "a=2:1:0.5", "a=1:2:-1", "a=0:4:*2", "a=x:2:1"])
def test_malformed_sweeps_are_rejected(text):
    with pytest.raises(InputError):
        parse_sweep(text)


def test_grid_and_list_entries_combine_into_one_override():
    grid = points([Sweep("mover.layers[0]", (1.0, 2.0)), Sweep("mover.layers[1]", (3.0,)),
                   Sweep("mover.name", ("yeoh",))])
    assert len(grid) == 2
    assert sorted(overrides_for(grid[1])) == ['mover.layers=[2.0, 3.0]', 'mover.name="yeoh"']
    with pytest.raises(InputError):
        overrides_for({"mover.layers[1]": 2.0})


def test_best_ignores_failed_runs():
    rows = [{"min_skewness": 0.2}, {"min_skewness": float("nan")}, {"converged": False}, {"min_skewness": 0.5}]
    assert best(rows)["min_skewness"] == 0.5


def test_csv_has_every_column_seen(tmp_path):
    write_csv(tmp_path / "t.csv", [{"a": 1}, {"a": 2, "b": 3}])
    rows = list(csv.DictReader(open(tmp_path / "t.csv")))
    assert rows == [{"a": "1", "b": ""}, {"a": "2", "b": "3"}]


def test_read_csv_restores_what_write_csv_wrote(tmp_path):
    rows = [{"value": 1e-10, "default": True, "mover": "spring", "error": float("nan")},
            {"value": 30.0, "default": False, "mover": "yeoh"}]
    back = read_csv(write_csv(tmp_path / "t.csv", rows))
    assert back[0]["value"] == 1e-10 and back[0]["default"] is True and back[0]["mover"] == "spring"
    assert np.isnan(back[0]["error"]) and np.isnan(back[1]["error"])       # blank cells come back as NaN
    assert back[1]["value"] == 30.0 and back[1]["default"] is False


def test_tofsi_study_sweeps_stiffening_and_reports_the_best(tmp_path):
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "study", str(scene_path("foil_in_channel")),
                          "--set", "mover.name=linear", "--set", "mesh.h_min=0.025",
                          "--sweep", "mover.layers[0]=1:4:3", "--output", str(tmp_path), "--json"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    rows = list(csv.DictReader(open(tmp_path / "study.csv")))
    assert [float(r["mover.layers[0]"]) for r in rows] == [1.0, 4.0]
    skew = [float(r["min_skewness"]) for r in rows]
    assert figures["best"]["min_skewness"] == pytest.approx(max(skew))
    assert (tmp_path / "study.png").is_file()


def test_tofsi_study_rejects_a_bad_sweep_key_before_running(tmp_path):
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "study", str(scene_path("foil_in_channel")),
                          "--sweep", "mover.yeoh.A21=1:2:1", "--output", str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "mover.yeoh.A21" in run.stderr
    assert not (tmp_path / "o").exists()
