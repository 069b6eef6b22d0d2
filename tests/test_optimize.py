"""The optimization driver: decreases, satisfies, writes where asked, and resumes exactly."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import tofsi
from tofsi.optimization.optimize import Optimizer, non_discreteness

from conftest import scene_path

TINY = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.25", "optimizer.max_iter=14",
        "design.stage_iterations=6"]


def run(output, on_iteration=None, resume=False, scene_overrides=TINY):
    scene = tofsi.load_scene(scene_path("beam_in_channel_optimization"), scene_overrides)
    opt = Optimizer(tofsi.Problem(scene), output, on_iteration=on_iteration)
    return opt, opt.run(resume=resume)


def test_a_few_iterations_decrease_the_objective_and_keep_the_volume(tmp_path):
    opt, result = run(tmp_path / "out")
    h = opt.history
    assert result["objective"] < 0.1 * h[0].objective
    assert result["constraint"] <= 1e-3                       # volume within 0.1 % of the bound
    assert result["volume"] == pytest.approx(opt.problem.volume(np.load(tmp_path / "out" / "design.npy")))
    assert {"history.csv", "history.json", "checkpoint.npz", "result.json", "design.npy"} <= \
        {p.name for p in (tmp_path / "out").iterdir()}


@pytest.mark.parametrize("scene, constraint", [("beam_in_channel_optimization", "solid"),
                                               ("double_pipe", "fluid")])
def test_a_design_past_the_volume_bound_is_shifted_onto_it_without_a_solve(scene, constraint):
    problem = tofsi.Problem(tofsi.load_scene(scene_path(scene), ["mesh.h_min=0.1", "mesh.h_max=0.1"]
                                             if scene != "double_pipe" else []))
    problem.set_stage(problem.stage.with_params(beta=8.0))
    bound = problem.scene.design.volume_fraction
    rng = np.random.default_rng(3)
    over = np.clip((0.55 if constraint == "solid" else 0.3) + 0.2 * rng.uniform(-1, 1, problem.n_design), 0, 1)
    assert problem.phase_fraction(over) > 1.1 * bound
    shifted = problem.feasible(over)
    # the bound less the 0.1 % margin, to the bisection's resolution
    assert problem.phase_fraction(shifted) == pytest.approx(bound * (1 - 1e-3), rel=1e-9)
    delta = over - shifted                                     # one uniform shift, clipped at 0 and 1
    moved = (shifted > 0) & (shifted < 1)
    assert np.ptp(delta[moved]) < 1e-12 and np.sign(delta[moved][0]) == (1 if constraint == "solid" else -1)
    assert problem.evaluations == 0                            # no flow or structure solve
    inside = problem.feasible(shifted)
    assert np.array_equal(inside, shifted)                     # a feasible design is kept


def test_every_stage_starts_within_the_volume_bound(tmp_path):
    # without the shift this schedule's last stage starts at g = +0.024
    opt, _ = run(tmp_path / "out", scene_overrides=TINY + ["design.stage_iterations=8", "optimizer.max_iter=40"])
    starts = [h for k, h in enumerate(opt.history) if k == 0 or h.stage != opt.history[k - 1].stage]
    assert len(starts) == 5 and all(h.constraint <= 1e-3 for h in starts)


def test_resume_after_an_interruption_reproduces_the_history_exactly(tmp_path):
    full, _ = run(tmp_path / "full")

    def interrupt(it):
        if it.iteration == 8:                                 # inside the second stage
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "cut", on_iteration=interrupt)
    resumed, _ = run(tmp_path / "cut", resume=True)
    key = lambda h: (h.iteration, h.stage, h.objective, h.volume, h.constraint, h.change, h.beta)
    assert [key(h) for h in resumed.history] == [key(h) for h in full.history]   # bitwise
    np.testing.assert_array_equal(np.load(tmp_path / "cut" / "design.npy"),
                                  np.load(tmp_path / "full" / "design.npy"))


def test_resume_without_a_checkpoint_is_an_input_error(tmp_path):
    from tofsi.core.errors import InputError
    with pytest.raises(InputError, match="no checkpoint"):
        run(tmp_path / "none", resume=True)


def test_tofsi_optimize_writes_only_into_its_output_folder(cli, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    before = set(os.listdir(scene_path("beam_in_channel_optimization").parent))
    args = ["optimize", scene_path("beam_in_channel_optimization"), "--output", "out", "--json",
            "--set", "optimizer.output_every=5"]
    for o in TINY:
        args += ["--set", o]
    proc = cli(*args, cwd=work)
    assert proc.returncode == 0, proc.stderr
    assert os.listdir(work) == ["out"]
    assert set(os.listdir(scene_path("beam_in_channel_optimization").parent)) == before
    names = set(os.listdir(work / "out"))
    assert {"design_0000.png", "design_0005.vtu", "design_series.pvd", "design_final.png",
            "convergence.png", "history.csv", "checkpoint.npz"} <= names
    figures = json.loads(proc.stdout)
    assert figures["iterations"] == 14 and "non_discreteness_percent" in figures


def test_non_discreteness_is_zero_for_black_and_white_and_100_for_grey():
    assert non_discreteness(np.array([0.0, 1.0, 1.0, 0.0])) == 0.0
    assert non_discreteness(np.full(7, 0.5)) == pytest.approx(100.0)


@pytest.mark.acceptance
def test_double_pipe_gives_two_separate_pipes(tmp_path):
    """Borrvall-Petersson, length 1: the fluid forms two straight pipes, solid between them."""
    scene = tofsi.load_scene(scene_path("double_pipe"), ["mesh.h_min=0.05", "mesh.h_max=0.05",
                                                        "optimizer.max_iter=60"])
    opt = Optimizer(tofsi.Problem(scene), tmp_path / "dp")
    result = opt.run()
    mesh = opt.problem.model.mesh
    fluid = 1 - opt.final_state.rho
    c = mesh.centroids
    middle = np.abs(c[:, 0] - 0.5) < 0.3
    assert fluid[middle & (np.abs(c[:, 1] - 0.25) < 0.05)].mean() > 0.8     # the lower pipe
    assert fluid[middle & (np.abs(c[:, 1] - 0.75) < 0.05)].mean() > 0.8     # the upper pipe
    assert fluid[middle & (np.abs(c[:, 1] - 0.5) < 0.05)].mean() < 0.2      # solid between
    assert result["constraint"] <= 1e-3


@pytest.mark.acceptance
def test_default_beam_in_channel_scene_end_to_end(tmp_path):
    """Issue acceptance on the shipped scene through the command line (about two minutes):
    the objective falls, the volume holds within 1 % of the bound, the design is nearly
    black and white, and the pictures a user expects are written."""
    scene = tofsi.load_scene(scene_path("beam_in_channel_optimization"))
    proc = subprocess.run([sys.executable, "-m", "tofsi.cli", "optimize",
                           str(scene_path("beam_in_channel_optimization")), "--output", str(tmp_path), "--json"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    history = json.loads((tmp_path / "history.json").read_text())
    assert result["objective"] < 1e-2 * history[0]["objective"]
    assert abs(result["volume"] - scene.design.volume_fraction) <= 0.01 * scene.design.volume_fraction
    assert result["non_discreteness_percent"] < 10.0
    assert {"convergence.png", "design_final.png", "design_series.pvd"} <= set(os.listdir(tmp_path))


@pytest.mark.acceptance
def test_double_pipe_objective_lies_between_the_published_values(tmp_path):
    """Full 50 x 50 double pipe (about a minute): two pipes, and a dissipation between
    topFlow's 22.0956 and Borrvall-Petersson's 25.67 (different meshes and discretizations)."""
    opt = Optimizer(tofsi.Problem(tofsi.load_scene(scene_path("double_pipe"))), tmp_path / "dp")
    result = opt.run()
    assert 22.0956 < result["objective"] < 25.67
    fluid = 1 - opt.final_state.rho
    c = opt.problem.model.mesh.centroids
    middle = np.abs(c[:, 0] - 0.5) < 0.3
    assert fluid[middle & (np.abs(c[:, 1] - 0.5) < 0.05)].mean() < 0.2
    assert result["constraint"] <= 1e-3


def test_the_serial_problem_is_a_design_problem_and_its_evaluation_is_one_record():
    """The optimizer's protocol: the serial Problem implements it, and its Evaluation holds what
    evaluate and constraints answer (the same arrays), the volume and the state's record."""
    from tofsi.optimization.protocol import DesignProblem, Evaluation
    problem = tofsi.Problem(tofsi.load_scene(scene_path("beam_in_channel_optimization"), TINY))
    assert isinstance(problem, DesignProblem)
    gamma = problem.initial_design()
    e = problem.evaluation(gamma)
    assert isinstance(e, Evaluation) and not e.failed and problem.evaluations == 1
    f, df = problem.evaluate(gamma)
    g, dg = problem.constraints(gamma)
    assert e.f == f and np.array_equal(e.df, df) and np.array_equal(e.g, g) and np.array_equal(e.dg, dg)
    assert e.volume == problem.volume(gamma) and e.state.linearizations == {}
    assert {"u", "w"} <= set(e.state.fields) and e.ramp == (0, 0)


def test_optimize_under_mpiexec_refuses_a_scene_the_distributed_problems_cannot_run(cli, tmp_path, monkeypatch):
    """Under mpiexec (two ranks, as the launcher's environment says) ``tofsi optimize`` of a
    finite-strain FSI scene is refused by name -- with the serial route named -- before
    petsc4py or a mesh is needed; ``solver.linear_solver = petsc`` keeps the serial problem
    on every rank."""
    monkeypatch.setenv("OMPI_COMM_WORLD_SIZE", "2")
    monkeypatch.setenv("OMPI_COMM_WORLD_RANK", "0")
    run = cli("optimize", scene_path("beam_in_channel_optimization"),
              *[a for s in [*TINY, "structure.model=neo-hookean"] for a in ("--set", s)], "--output", tmp_path / "o")
    assert (run.returncode == 2 and "structure.model" in run.stderr
            and "solver.linear_solver = 'petsc'" in run.stderr), run.stderr
