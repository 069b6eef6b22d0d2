"""Tuned stiffening: the soft quality's derivatives, the tuning gradient, the optimizer, ``tofsi tune``."""

import json

import numpy as np
import pytest

from adjoint.checks import central_difference, relative_error, taylor_test
from tofsi.core.errors import InputError, NumericalError
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.coupling.motion import motion_setup, move_figures
from tofsi.mesh.quality import area_change, skewness
from tofsi.mesh.soft_quality import (area_change_vjp, corner_skewness, corner_skewness_vjp, soft_max,
                                soft_min)
from tofsi.optimization.tuning import TuningProblem, parametrization, tune

from conftest import load, scene_path

COARSE = ["mesh.h_min=0.025", "mesh.h_max=0.1"]
P_KS = 60.0                      # the KS parameter of the first stage


def distorted_mesh(seed=0):
    mesh = StructuredQuadMesh(np.linspace(0, 1, 7), np.linspace(0, 1, 6))
    return mesh, mesh.points + 0.04 * np.random.default_rng(seed).normal(size=mesh.points.shape)


# ---- the soft quality and its derivatives ---------------------------------------------------
def test_corner_skewness_is_the_elements_skewness_on_valid_meshes():
    mesh, X = distorted_mesh()
    assert np.all(skewness(X, mesh.quads) > 0)
    np.testing.assert_allclose(corner_skewness(X, mesh.quads).min(axis=1), skewness(X, mesh.quads), atol=1e-14)


def test_ks_soft_minimum_bounds_the_minimum_and_its_weights_are_its_gradient():
    values = np.random.default_rng(1).uniform(0.2, 1.0, 500)
    for p in (10.0, 60.0, 400.0):
        ks, w = soft_min(values, p)
        assert values.min() - np.log(values.size) / p <= ks <= values.min()
        d, h = np.random.default_rng(2).normal(size=values.size), 1e-6
        fd = (soft_min(values + h * d, p)[0] - soft_min(values - h * d, p)[0]) / (2 * h)
        assert fd == pytest.approx(w @ d, rel=1e-7)
    assert soft_max(values, 60.0)[0] == pytest.approx(-soft_min(-values, 60.0)[0])


@pytest.mark.parametrize("which", ["skewness", "area change"])
def test_quality_derivatives_match_central_differences(which):
    mesh, X = distorted_mesh(3)
    rng = np.random.default_rng(4)
    if which == "skewness":
        w = rng.normal(size=(mesh.n_elements, 4))
        value = lambda P: float(np.sum(w * corner_skewness(P, mesh.quads)))
        grad = corner_skewness_vjp(X, mesh.quads, w)
    else:
        w = rng.normal(size=mesh.n_elements)
        value = lambda P: float(w @ area_change(mesh.points, P, mesh.quads))
        grad = area_change_vjp(mesh.points, X, mesh.quads, w)
    d = rng.normal(size=X.shape)
    assert relative_error(central_difference(value, X, d, 1e-6), np.sum(grad * d)) < 1e-8


def test_soft_skewness_is_continuous_where_a_corner_collapses():
    """A corner pushed through 0 degrees: the tuning measure goes on slightly below 0,
    where the project's skewness jumps from 0 to -2 (its angle wraps to 360)."""
    quad = np.array([[0, 1, 2, 3]])
    angles = []                       # a parallelogram whose corner 0 (angle a) closes and folds
    for a in np.radians([2.0, 0.5, -0.5, -2.0]):
        P = np.array([[0.0, 0.0], [1.0, 0.0], [1.0 + np.cos(a), np.sin(a)], [np.cos(a), np.sin(a)]])
        angles.append(corner_skewness(P, quad)[0, 0])
    np.testing.assert_allclose(angles, np.array([2.0, 0.5, -0.5, -2.0]) / 90, atol=1e-12)   # s = a / 90
    assert skewness(np.array([[0.0, 0.0], [1.0, 0.0], [1.0 + np.cos(-0.01), np.sin(-0.01)],
                              [np.cos(-0.01), np.sin(-0.01)]]), quad)[0] < -1.9   # the report's measure


# ---- the tuning gradient: adjoint of the mover chained to the factors ------------------------
def tuning_problem(mover, *overrides):
    scene = load("beam_in_channel", *COARSE, f"mover.name={mover}", *overrides)
    setup = motion_setup(scene)
    param = parametrization(setup, scene.tune, scene.mover.layers)
    return TuningProblem(setup, scene.tune, param), param


def _taylor(problem, z, d, fun=None):
    fun = fun or (lambda x, g=None: problem.objective(x, g, P_KS))
    g = np.zeros(z.size)
    f0 = fun(z, g)
    return taylor_test(lambda x: fun(x, None), z, g, d, eps0=2e-2, steps=4, f0=f0), g


@pytest.mark.parametrize("mover,params", [("linear", ["mover.linear.linear_tol=1e-15"]),
                                          ("yeoh", ["mover.yeoh.newton_tol=1e-13", "mover.yeoh.linear_tol=1e-15"])])
@pytest.mark.parametrize("param", ["layers", "profile"])
def test_tuning_gradient_passes_the_taylor_test(mover, params, param):
    problem, p = tuning_problem(mover, *params, f"tune.parametrization={param}", "tune.layers=4",
                                "mover.layers=[3.0, 2.0, 1.5]")
    rng = np.random.default_rng(5)
    z = p.x0 + (0.0 if param == "layers" else np.array([1.5, 0.3]))
    t, _ = _taylor(problem, z, rng.normal(size=z.size))
    assert t.min_rate > 1.9, t


def test_area_bound_gradients_pass_the_taylor_test():
    problem, p = tuning_problem("linear", "mover.linear.linear_tol=1e-15", "tune.layers=3",
                                "tune.min_area_change=0.5", "tune.max_area_change=2.0", "mover.layers=[3.0, 2.0]")
    d = np.random.default_rng(6).normal(size=p.x0.size)
    for upper in (True, False):
        t, _ = _taylor(problem, p.x0, d, lambda z, g, upper=upper: problem.area_bound(z, g, P_KS, upper))
        assert t.min_rate > 1.9, (upper, t)


def test_spring_tuning_gradient_matches_central_differences_with_fixed_diagonals():
    problem, p = tuning_problem("spring", "mover.spring.diagonals=both", "mover.spring.increments=4",
                                "mover.spring.linear_tol=1e-15", "tune.layers=3", "mover.layers=[2.0, 1.5]")
    rng = np.random.default_rng(7)
    g = np.zeros(p.x0.size)
    problem.objective(p.x0, g, P_KS)
    for _ in range(2):
        d = rng.normal(size=p.x0.size)
        cd = central_difference(lambda z: problem.objective(z, None, P_KS), p.x0, d, 1e-5)
        assert relative_error(cd, g @ d) < 1e-6, (cd, g @ d)


def test_a_missing_chain_term_breaks_the_taylor_test(monkeypatch):
    """Teeth: dropping the factor's own scaling from the layer map leaves a first-order remainder."""
    problem, p = tuning_problem("linear", "mover.linear.linear_tol=1e-15", "tune.layers=3",
                                "mover.layers=[3.0, 2.0, 1.5]")
    monkeypatch.setattr(type(p), "layer_jacobian", lambda self, z: np.eye(z.size))
    t, _ = _taylor(problem, p.x0, np.random.default_rng(8).normal(size=p.x0.size))
    assert t.min_rate < 1.3, t


# ---- the optimizer --------------------------------------------------------------------------
def two_layer_grid_search(base):
    """The paper's two-layer search as ``examples/mesh_motion_study.py`` runs it: factors 1 to 6
    by 0.5, then the best +- 0.5 by 0.1; every point one move. Returns the best and the count."""
    def min_skewness(a, b):
        try:
            return move_figures(load("beam_in_channel", *base, f"mover.layers=[{a}, {b}]"))["min_skewness"]
        except NumericalError as err:                       # inverted: its (negative) skewness
            return err.diagnostic["quality"]["min_skewness"]
    coarse = np.arange(1.0, 6.01, 0.5)
    points = {(a, b): min_skewness(a, b) for a in coarse for b in coarse}
    a0, b0 = max(points, key=points.get)
    window = lambda c: np.round(np.arange(max(1.0, c - 0.5), c + 0.501, 0.1), 6)
    fine = {(a, b): min_skewness(a, b) for a in window(a0) for b in window(b0)}
    return max([*points.values(), *fine.values()]), len(points) + len(fine)


@pytest.mark.parametrize("mover", ["linear", pytest.param("yeoh", marks=pytest.mark.slow)])
def test_tuning_beats_the_two_layer_grid_search_with_a_tenth_of_its_solves(mover):
    """Coarse beam: the best point of the grid search (its own moves are the truth) against
    tuning given a tenth of the grid's moves as mover solves, moves and adjoints together."""
    base = [f"mover.name={mover}", *COARSE]
    grid_best, grid_moves = two_layer_grid_search(base)
    result = tune(load("beam_in_channel", *base, f"tune.max_solves={grid_moves // 10}"))
    assert result.moves + result.adjoints <= grid_moves // 10
    check = move_figures(load("beam_in_channel", *base, "mover.layers=[" +
                              ", ".join(map(repr, result.layer_factors)) + "]"))
    assert check["min_skewness"] == pytest.approx(result.min_skewness, abs=1e-9)   # reproducible
    assert result.min_skewness >= grid_best, (result.min_skewness, grid_best)


def test_area_bounds_are_met_by_the_tuned_factors():
    scene = load("beam_in_channel", "mover.name=linear", *COARSE, "mover.layers=[3.0, 2.0]",
                 "tune.max_area_change=1.15", "tune.max_solves=30", "tune.algorithm=SLSQP")
    free = tune(load("beam_in_channel", "mover.name=linear", *COARSE, "mover.layers=[3.0, 2.0]",
                     "tune.max_solves=20"))
    bounded = tune(scene)
    assert free.max_area_change > 1.15                      # the bound is active
    assert bounded.max_area_change <= 1.15 + 1e-3


def test_bad_tune_settings_are_input_errors():
    with pytest.raises(InputError, match="tune.max_factor"):
        load("beam_in_channel", "tune.min_factor=3", "tune.max_factor=2")
    with pytest.raises(InputError, match="tune.algorithm"):
        tune(load("beam_in_channel", "mover.name=linear", "tune.algorithm=LBFGS", "tune.max_area_change=2"))
    with pytest.raises(InputError, match="geometry.design"):
        tune(load("beam_in_channel_optimization", "mover.name=linear"))


# ---- the command line ----------------------------------------------------------------------
def test_tofsi_tune_json_outputs_and_set(tmp_path, cli):
    run = cli("tune", scene_path("beam_in_channel"), "--set", "mover.name=linear", *sum(
        (["--set", o] for o in COARSE), []), "--set", "tune.max_solves=8", "--set", "tune.layers=2",
        "--output", tmp_path, "--json")
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)                     # stdout is the JSON object alone
    assert {"min_skewness", "min_area_change", "max_area_change", "layer_factors", "moves",
            "adjoints", "n_inverted", "wall_time_s"} <= set(figures)
    assert len(figures["layer_factors"]) == 2 and 1 <= figures["moves"] + figures["adjoints"] <= 8
    assert {"tune.json", "tune_history.csv", "tuned_mesh.vtu", "tuned_mesh.png", "run.json"} == \
        {p.name for p in tmp_path.iterdir()}
    saved = json.loads((tmp_path / "tune.json").read_text())
    assert max(h["min_skewness"] for h in saved["history"]) == pytest.approx(figures["min_skewness"])
    assert saved["settings"]["tune"]["max_solves"] == 8 and saved["settings"]["mover"]["name"] == "linear"
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["exit_status"] == 0 and "tune" in record["command_line"]
    assert "tuned factors" in run.stderr                 # the summary goes to stderr with --json
    assert "tune: " in run.stderr                        # progress lines (not a terminal)
    again = cli("tune", scene_path("beam_in_channel"), "--set", "mover.name=linear", "--output", tmp_path)
    assert again.returncode == 2 and "--overwrite" in again.stderr   # another run's folder


def test_tofsi_tune_bad_input_exits_2_and_numerical_failure_exits_3(tmp_path, cli):
    run = cli("tune", scene_path("beam_in_channel"), "--set", "tune.ks=-1", "--output", tmp_path / "a")
    assert run.returncode == 2 and "tune.ks" in run.stderr and "Traceback" not in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and not (tmp_path / "a").exists()
    run = cli("tune", scene_path("foil_in_channel"), "--set", "mover.name=yeoh", "--set",
              "deformation.translation=0.474", "--set", "mover.yeoh.max_cutbacks=4", "--set",
              "tune.max_solves=4", "--output", tmp_path / "b", "--json")
    assert run.returncode == 3, run.stderr
    assert (tmp_path / "b" / "diagnostic.json").is_file() and json.loads(run.stdout)["converged"] is False
    run = cli("tune", scene_path("foil_in_channel"), "--set", "deformation.translation=0.6",
              "--output", tmp_path / "c")               # out of the channel: bad input, nothing built
    assert run.returncode == 2 and "deformation.translation" in run.stderr
    assert not (tmp_path / "c").exists()
