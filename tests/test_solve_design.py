"""``tofsi solve`` analyses a design through optimize's filter and projection."""

import json
import subprocess
import sys

import pytest

from conftest import scene_path

OPT = str(scene_path("beam_in_channel_optimization"))
TINY = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.15", "design.stage_iterations=2",
        "optimizer.max_iter=11"]             # stages 0-3 two iterations each, the last three


def tofsi(cli, command, *args, cwd, scene=OPT, small=True):
    sets = [a for o in TINY for a in ("--set", o)] if small else []
    return cli(command, scene, *sets, *args, cwd=cwd)


@pytest.fixture(scope="module")
def optimized(tmp_path_factory):
    work = tmp_path_factory.mktemp("optimized")
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "optimize", OPT, "--output", "opt", "--json",
                          *[a for o in TINY for a in ("--set", o)]], capture_output=True, text=True, cwd=work)
    assert run.returncode == 0, run.stderr
    return work, json.loads(run.stdout)


def test_solve_of_the_uniform_design_reproduces_optimize_iteration_0(cli, optimized, tmp_path):
    """The reproduction: solve gave 50.80 against optimize's 53.64 (no filter or projection).
    Now the uniform design goes through stage 0's map, as optimize's first evaluation does."""
    work, _ = optimized
    history = json.loads((work / "opt" / "history.json").read_text())
    run = tofsi(cli, "solve", "--output", "s", "--json", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    assert figures["compliance"] == pytest.approx(history[0]["objective"], rel=1e-9)
    assert figures["objective"] == pytest.approx(history[0]["objective"], rel=1e-9)
    assert figures["volume"] == pytest.approx(history[0]["volume"], rel=1e-12)
    assert figures["design"] == "uniform" and figures["stage"] == 0


def test_the_shipped_scene_at_full_size_gives_optimizes_iteration_0(cli, tmp_path):
    """Optimize's iteration-0 compliance of the shipped scene (reaction load, E = 1e7 Pa, first
    stage q = 0.01; history.csv of the full run): 0.453459 J/m (5.61771 at q = 0.1; 53.64 with
    the old stress-divergence load at E = 1e5, where solve gave 50.80)."""
    run = tofsi(cli, "solve", "--output", "s", "--json", cwd=tmp_path, small=False)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["compliance"] == pytest.approx(0.45345869, rel=1e-6)


def test_solve_of_a_saved_design_at_the_last_stage_reproduces_result_json(cli, optimized, tmp_path):
    work, result = optimized
    design = work / "opt" / "design.npy"
    run = tofsi(cli, "solve", "--design", design, "--stage", "last", "--output", "s", "--json",
                cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    for key in ("objective", "volume", "compliance", "pressure_drop", "drag"):
        assert figures[key] == pytest.approx(result[key], rel=1e-8), key
    assert figures["design"] == str(design) and figures["beta"] == 16.0 and result["stage"] == 4
    stopped_early = tofsi(cli, "solve", "--design", design, "--stage", "2", "--output", "s2", "--json",
                          cwd=tmp_path)
    assert json.loads(stopped_early.stdout)["beta"] == 4.0            # a run that ended in stage 2


def test_design_option_is_design_initial(cli, optimized, tmp_path):
    work, _ = optimized
    design = work / "opt" / "design.npy"
    a = tofsi(cli, "solve", "--design", design, "--output", "a", "--json", cwd=tmp_path)
    b = tofsi(cli, "solve", "--set", f"design.initial={design}", "--output", "b", "--json",
              cwd=tmp_path)
    assert a.returncode == b.returncode == 0
    fa, fb = json.loads(a.stdout), json.loads(b.stdout)
    assert fa["compliance"] == fb["compliance"] and fa["stage"] == fb["stage"] == 0
    record = json.loads((tmp_path / "a" / "run.json").read_text())
    assert f'initial = "{design}"' in record["scene"]

