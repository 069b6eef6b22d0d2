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



# ---- issue 36, item 2: a saved design a user can re-solve ---------------------------------------
LARGE = str(scene_path("beam_in_channel_optimization_large"))
LARGE_COARSE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "structure.youngs_modulus=1.5e4"]
"""The large-deformation example at a tenth of the channel per element (ten times stiffer, as the
shipped-scene test runs it there): three one-way stages of 20 iterations, then four two-way
finite-strain iterations (stage 3)."""


@pytest.mark.acceptance
def test_the_large_examples_design_is_re_solved_from_its_run(cli, tmp_path):
    """The quoted figures existed only on the optimizer's warm-start path: a cold solve of the
    same design (stage 3) reaches another coupled state here (compliance 1.717 against the run's
    2.041, every block's residual at its tolerance in both: two equilibria of this design), and
    at full size stopped at 0.12 of the inflow. --from RUN starts from the run's final state and
    reproduces result.json to the solver tolerance."""
    sets = [a for o in LARGE_COARSE for a in ("--set", o)]
    run = cli("optimize", LARGE, *sets, "--set", "optimizer.max_iter=64", "--output", tmp_path / "run", "-q")
    assert run.returncode == 0, run.stderr
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["stage"] == 3 and result["physical"] and (tmp_path / "run" / "final_state.npz").is_file()
    again = cli("solve", LARGE, *sets, "--from", tmp_path / "run", "--output", tmp_path / "again", "--json")
    assert again.returncode == 0, again.stderr
    figures = json.loads(again.stdout)
    assert figures["stage"] == 3 and figures["design"] == str(tmp_path / "run" / "design.npy")
    for key in ("compliance", "max_solid_displacement", "pressure_drop", "min_skewness", "volume"):
        assert figures[key] == pytest.approx(result[key if key != "compliance" else "objective"], rel=1e-8), key


def test_a_failed_cold_solve_of_a_design_suggests_starting_from_the_run(cli, tmp_path, monkeypatch):
    from tofsi.coupling.coupled import CoupledModel
    from tofsi.core.errors import NumericalError

    def cold(self, rho, guess=None, progress=None, stage=None):
        raise NumericalError("load continuation stopped at 0.1211 of the inflow (forced)")
    monkeypatch.setattr(CoupledModel, "solve", cold)
    run = cli("solve", LARGE, *[a for o in LARGE_COARSE for a in ("--set", o)], "--stage", "last",
              "--output", tmp_path / "out")
    line = run.stderr.strip().splitlines()[-1]
    assert run.returncode == 3 and "a cold solve starts from rest" in line and "--from RUN" in line, line


@pytest.mark.parametrize("case,says", [("missing", "no such folder"), ("no state", "holds no final_state.npz"),
                                       ("no design region", "no design region")])
def test_from_a_folder_without_a_final_state_is_refused(case, says, cli, tmp_path):
    (tmp_path / "run").mkdir()
    scene = str(scene_path("foil_in_channel")) if case == "no design region" else OPT
    if case == "no design region":
        (tmp_path / "run" / "final_state.npz").write_bytes(b"")
    folder = tmp_path / ("nowhere" if case == "missing" else "run")
    run = cli("solve", scene, "--from", folder, "--output", tmp_path / "out")
    lines = run.stderr.strip().splitlines()
    key = "design.initial" if case == "no design region" else "--from"       # RUN's design.npy
    assert run.returncode == 2 and len(lines) == 1 and key in lines[0] and says in lines[0], run.stderr
    assert not (tmp_path / "out").exists()
