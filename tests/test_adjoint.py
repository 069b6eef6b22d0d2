"""Adjoint gradients: dot-product tests, Taylor tests and central differences, with teeth.

Tolerances: Taylor remainder rate > 1.9 (a missing term shows as ~1);
central-difference relative error < 1e-6 for Stokes and < 1e-5 for
Navier-Stokes (forward solves are converged to round-off here).
"""

import numpy as np
import pytest

import tofsi
from adjoint import Adjoint
from adjoint.checks import central_difference, relative_error
from tofsi.optimization.design import DensityFilter, DesignMap, Projection
from tofsi.core.errors import NumericalError
from tofsi.mesh.structured import DESIGN

from conftest import load
from gradient_checks import check_total_derivative

BASE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13",
        "design.filter_radius=0.15", "structure.youngs_modulus=2e4", "coupled.tol=1e-12",
        "mover.yeoh.newton_tol=1e-13", "mover.linear.linear_tol=1e-14", "mover.spring.linear_tol=1e-14"]
MOVERS = {"yeoh": ["mover.name=yeoh"], "linear": ["mover.name=linear"],
          "spring-1": ["mover.name=spring", "mover.spring.increments=1", "mover.spring.diagonals=both"],
          "spring-3": ["mover.name=spring", "mover.spring.increments=3", "mover.spring.diagonals=both"]}
# (selective diagonals are re-chosen from trial increments, so the map jumps where a choice
#  flips: its gradient is exact between switches, but a Taylor test may straddle one)
SHARP = ["design.filter_radius=0.01", "design.beta=[0.0]"]        # identity map: rho = gamma


def problem(*overrides):
    return tofsi.Problem(load("beam_in_channel_optimization", *BASE, *overrides))


def design_and_direction(P, sharp, seed=0):
    rng = np.random.default_rng(seed)
    if sharp:            # densities exactly 0 and 1 (a post on the clamped wall, no floating
        c = P.model.mesh.centroids[P.map.design]        # islands); directions stay in [0, 1]
        gamma = ((np.abs(c[:, 0] - 1.0) < 0.25) & (c[:, 1] < 0.45)).astype(float)
        d = np.where(gamma > 0.5, -1.0, 1.0) * rng.uniform(0.2, 1.0, P.n_design)
    else:
        gamma = rng.uniform(0.05, 0.95, P.n_design)
        d = rng.normal(size=P.n_design)
    return gamma, d


@pytest.mark.parametrize("sharp", [False, True], ids=["random design", "0/1 densities"])
@pytest.mark.parametrize("fluid", ["stokes", "navier-stokes"])
@pytest.mark.parametrize("objective", ["compliance", "dissipation", "pressure-drop"])
def test_one_way_total_derivatives(objective, fluid, sharp):
    P = problem(f"design.objective={objective}", f"effects.fluid={fluid}", *(SHARP if sharp else []))
    gamma, d = design_and_direction(P, sharp)
    t, err, _ = check_total_derivative(P, gamma, d, eps0=1e-3 if sharp else 1e-2)
    assert t.min_rate > 1.9, t
    assert err < (1e-6 if fluid == "stokes" else 1e-5), err


TWO_WAY = [  # (objective, mover, sharp): every mover on both designs, every objective on both
    ("compliance", "yeoh", False), ("dissipation", "linear", False), ("pressure-drop", "spring-1", False),
    ("compliance", "spring-3", False), ("dissipation", "yeoh", True), ("pressure-drop", "linear", True),
    ("compliance", "spring-1", True), ("dissipation", "spring-3", True)]


@pytest.mark.parametrize("objective,mover,sharp", TWO_WAY,
                         ids=[f"{o}-{m}-{'0/1 densities' if s else 'random design'}" for o, m, s in TWO_WAY])
def test_two_way_total_derivatives(objective, mover, sharp):
    """The partitioned two-way adjoint, each mover (its Jacobian and transposes, the spring's
    single step and its increments) on a random design and on 0/1 densities. The objectives
    differ here only in the adjoint's right-hand side (compliance: u and x; dissipation: w and
    x; pressure drop: w), whose values and partials are checked elsewhere
    (test_one_way_total_derivatives: every objective, both fluids, both designs;
    test_shape_derivatives.py: the x partials), so the full product of 24 cases repeats itself:
    the 8 cases rotate the objectives so that each meets both designs and at least two movers.
    The monolithic path is test_monolithic_adjoint_matches_central_differences."""
    P = problem(f"design.objective={objective}", "effects.coupling=two-way", *MOVERS[mover],
                "structure.load_exponent=3", "coupled.method=partitioned", *(SHARP if sharp else []))
    gamma, d = design_and_direction(P, sharp, seed=1)
    t, err, _ = check_total_derivative(P, gamma, d, eps0=1e-3 if sharp else 1e-2)
    assert t.min_rate > 1.9, t
    assert err < 1e-5, err


@pytest.mark.parametrize("mover", ["yeoh", "linear", "spring-1", "spring-3"])
def test_monolithic_adjoint_matches_central_differences(mover):
    """The monolithic Newton's adjoint (the transposed block Jacobian; with the spring in
    increments its coupling is the reverse sweep through them, a LinearMap's transpose)."""
    P = problem("effects.coupling=two-way", "coupled.method=monolithic", "effects.fluid=stokes",
                *MOVERS[mover])
    gamma, d = design_and_direction(P, False, seed=2)
    t, err, _ = check_total_derivative(P, gamma, d)
    assert Adjoint(P.model.system, P.solve(gamma)).method() == "monolithic"
    assert t.min_rate > 1.9 and err < 1e-6, (t, err)


def test_volume_constraint_needs_no_solve_and_is_exact():
    P = problem()
    gamma, d = design_and_direction(P, False)
    g, dg = P.constraints(gamma)
    fd = central_difference(lambda x: P.constraints(x)[0][0], gamma, d, 1e-5)
    assert relative_error(fd, dg[0] @ d) < 1e-7          # O(h^2) and round-off at h = 1e-5
    state = P.solve(gamma)
    adj = Adjoint(P.model.system, state)
    adj.gradient(P.volume_fraction.partials(P.model, state))
    assert adj.reports == []                                    # no adjoint solve was made


@pytest.mark.parametrize("block", ["S_x", "F_x"])
def test_dropping_a_coupling_block_breaks_the_taylor_test(block, monkeypatch):
    """The check has teeth: without S_x (or F_x) the remainder falls only like eps."""
    P = problem("effects.coupling=two-way", *MOVERS["yeoh"], "structure.youngs_modulus=3e3")
    gamma, d = design_and_direction(P, False, seed=3)
    from tofsi.fields.flow import FlowLinearization
    from tofsi.fields.structure import StructureLinearization
    cls = StructureLinearization if block == "S_x" else FlowLinearization
    original = cls.coupling
    monkeypatch.setattr(cls, "coupling", lambda self, other: 0 * original(self, other)
                        if other == "x" else original(self, other))
    t, err, _ = check_total_derivative(P, gamma, d)
    assert t.min_rate < 1.3, t                                  # first order: a term is missing
    assert err > 1e-4, err                                      # and the central difference sees it


def test_adjoint_refuses_an_unconverged_state():
    P = problem()
    state = P.solve(P.initial_design())
    state.converged = False
    with pytest.raises(NumericalError, match="not converged"):
        Adjoint(P.model.system, state)


def test_newton_iteration_limit_raises_instead_of_returning_a_gradient():
    P = problem("fluid.newton_max_iter=1", "fluid.continuation_steps=1", "fluid.density=50.0")
    with pytest.raises(NumericalError):
        P.evaluate(P.initial_design())


# ---- dot-product tests for every transposed operator ------------------------------------
def _dot(forward, transpose, n_in, n_out, seed=5):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=n_in), rng.normal(size=n_out)
    return forward(a) @ b, a @ transpose(b)


def test_filter_projection_and_design_map_transposes():
    rng = np.random.default_rng(4)
    P = problem()
    mesh = P.model.mesh
    design = np.flatnonzero(mesh.region == DESIGN)
    F = DensityFilter(mesh, design, 0.3)
    lhs, rhs = _dot(lambda a: F.forward(a) - F.forward(0 * a), F.transpose, design.size, design.size)
    assert lhs == pytest.approx(rhs, rel=1e-13)
    proj = Projection(8.0, 0.4)
    x = rng.uniform(0, 1, 60)
    lhs, rhs = _dot(lambda a: proj.derivative(x) * a, lambda b: proj.transpose(x, b), 60, 60)
    assert lhs == pytest.approx(rhs, rel=1e-13)
    M = DesignMap(P.model.mesh, 0.2)
    g = rng.uniform(0, 1, M.size)
    h = 1e-6
    Jv = lambda a: (M.forward(g + h * a, 4.0) - M.forward(g - h * a, 4.0)) / (2 * h)
    lhs, rhs = _dot(Jv, lambda b: M.transpose(g, 4.0, b), M.size, P.model.mesh.n_elements)
    assert lhs == pytest.approx(rhs, rel=1e-8)


def test_mesh_motion_maps_and_solver_transposes():
    P = problem("effects.coupling=two-way", *MOVERS["yeoh"])
    motion = P.model.motion
    n = P.model.mesh.n_nodes
    lhs, rhs = _dot(lambda a: motion.target(a).ravel(), motion.target_transpose, 2 * n, 2 * n)
    assert lhs == pytest.approx(rhs, rel=1e-13)
    from tofsi.physics.mesh_motion import solid_indicator
    rho = np.random.default_rng(6).uniform(0, 1, P.model.mesh.n_elements)
    _, ds = solid_indicator(rho, P.model.mesh.quads, n)
    lhs, rhs = _dot(lambda a: ds @ a, lambda b: motion.density_transpose(rho, b), rho.size, n)
    assert lhs == pytest.approx(rhs, rel=1e-13)
    state = P.solve(P.initial_design())
    J = P.model.system.jacobian(state.linearizations, P.model.system.names)
    from tofsi.linalg import DirectSolver
    S = DirectSolver(J)
    lhs, rhs = _dot(S.solve, S.solve_transpose, J.shape[0], J.shape[0])
    assert lhs == pytest.approx(rhs, rel=1e-9)


def test_check_gradients_command_passes_and_fails_with_status_1(tmp_path, monkeypatch, capsys):
    from tofsi.cli import main
    from conftest import scene_path
    args = ["check-gradients", str(scene_path("beam_in_channel_optimization")), "--set", "mesh.h_min=0.1",
            "--set", "mesh.h_max=0.1", "--output", str(tmp_path), "--json", "-q", "--overwrite"]
    assert main(args) == 0
    import json
    out = json.loads(capsys.readouterr().out)
    assert out["passed"] and {r["check"] for r in out["checks"]} >= {"F_w", "S_u", "S_w", "S_rho",
                                                                      "objective compliance"}
    from tofsi.fields.structure import StructureLinearization
    original = StructureLinearization.transpose_partials

    def wrong_S_rho(self, lam):                       # S_rho 1 % too large
        inputs, rho_bar = original(self, lam)
        return inputs, 1.01 * rho_bar
    monkeypatch.setattr(StructureLinearization, "transpose_partials", wrong_S_rho)
    assert main(args) == 1
    out = json.loads(capsys.readouterr().out)
    failed = {r["check"] for r in out["checks"] if not r["passed"]}
    assert "S_rho" in failed and "objective compliance" in failed


def test_check_gradients_passes_on_the_iterative_path(tmp_path, capsys):
    """On the iterative path the check tightens the flow's Newton and the adjoint's transposed
    GMRES (:func:`tofsi.commands.check_gradients.checked_scene`): with the scene's own
    tolerances the central difference of the compliance was 4.3e-5 off its right gradient
    (FAILED against 1e-5; 210 elements); tightened, 2.6e-8."""
    import json
    from tofsi.cli import main
    from tofsi.commands.check_gradients import CHECK_ADJOINT_TOL, CHECK_FLOW_TOL, checked_scene
    from conftest import load, scene_path
    scene = checked_scene(load("beam_in_channel_optimization", "solver.linear_solver=iterative"))
    assert scene.fluid.newton_tol == CHECK_FLOW_TOL and scene.solver.adjoint_tol == CHECK_ADJOINT_TOL
    args = ["check-gradients", str(scene_path("beam_in_channel_optimization")), "--set", "mesh.h_min=0.1",
            "--set", "mesh.h_max=0.1", "--set", "solver.linear_solver=iterative", "--output", str(tmp_path),
            "--json", "-q", "--overwrite"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    total = next(r for r in out["checks"] if r["check"] == "objective compliance")
    assert out["passed"] and total["result"] == "ok" and total["cd_error"] < 1e-6
