"""``solver.linear_solver = "iterative"``: gradients and optimizations without an LU.

Stated tolerances: the flow's Newton converges to the scene's tolerance with
GMRES steps, the adjoint's transposed GMRES to ``solver.adjoint_tol`` (3e-6, what
the gradient needs: ``tofsi.linalg.iterative``'s docstring); the objective
then equals the direct path's to 1e-8 and its gradient to 1e-4 relative
(measured 9.2e-10 and 1.3e-5 at 800 elements on 2026-11-27, 6.3e-6 at 1e-6: the compliance
gradient is a difference of flow and structure parts several times its size,
so its error is 3-10 times the adjoint's residual on this mesh), and to
1e-6 with the adjoint asked for 1e-8 (measured 1.2e-7); the Taylor test of
the iterative gradient passes (rate > 1.9), and a 14-iteration
optimization's objective history equals the direct path's to 1e-4 relative
(measured 6.6e-6; 4.9e-6 at 1e-6), and (slow) a
60-iteration one over three stages ends at the direct path's design to half
the optimizer's stopping change ``optimizer.tol_change`` (measured 2.8e-4
against 1e-3; 1.4e-4 at 1e-6, 3.6e-4 at 5e-6, 2.7e-3 with the adjoint to 1e-5
before the transposed preconditioner's Darcy weight).
"""

import numpy as np
import pytest

import tofsi
from adjoint.checks import taylor_test
from tofsi.linalg import AMGSolver
from tofsi.linalg.iterative import BlockSaddlePreconditioner
from tofsi.optimization.optimize import Optimizer

from conftest import load

COARSE = ["mesh.h_min=0.05", "mesh.h_max=0.05"]
ITERATIVE = ["solver.linear_solver=iterative"]


def problem(*overrides):
    return tofsi.Problem(load("beam_in_channel_optimization", *COARSE, *overrides))


def test_the_model_solves_without_an_lu():
    """The flow's Newton steps are GMRES with the block preconditioner; the structure's solve
    is AMG-CG; both belong to this model only (a direct model beside it keeps its LU)."""
    P, D = problem(*ITERATIVE), problem()
    assert P.model.linear_algebra.iterative and not D.model.linear_algebra.iterative
    rho = P.model.densities()
    solution = P.model.flow.newton_solve(None, rho)
    assert isinstance(solution.solver.solver, BlockSaddlePreconditioner)
    assert isinstance(P.model.structure.factorize(rho), AMGSolver)
    assert not isinstance(D.model.flow.newton_solve(None, rho).solver.solver, BlockSaddlePreconditioner)


@pytest.mark.parametrize("adjoint_tol, gradient_tol", [(None, 1e-4), (1e-8, 1e-6)])
def test_objective_and_gradient_equal_the_direct_path(adjoint_tol, gradient_tol):
    """At the default adjoint tolerance, and with a tighter one asked for (``solver.adjoint_tol``;
    the default's gradient, 1.3e-5 off, fails the tighter bound, so the request is seen)."""
    asked = [] if adjoint_tol is None else [f"solver.adjoint_tol={adjoint_tol}"]
    gamma = np.random.default_rng(0).uniform(0.05, 0.95, problem().n_design)
    f_it, g_it = problem(*ITERATIVE, *asked).evaluate(gamma)
    f_lu, g_lu = problem().evaluate(gamma)
    assert abs(f_it - f_lu) <= 1e-8 * abs(f_lu)
    assert np.linalg.norm(g_it - g_lu) <= gradient_tol * np.linalg.norm(g_lu)


@pytest.mark.parametrize("objective", ["compliance", "dissipation"])
def test_taylor_test_passes_on_the_iterative_path(objective):
    P = problem(*ITERATIVE, f"design.objective={objective}")
    rng = np.random.default_rng(1)
    gamma = rng.uniform(0.05, 0.95, P.n_design)
    direction = rng.normal(size=P.n_design)
    f0, df = P.evaluate(gamma)
    t = taylor_test(lambda g: P.evaluate(g)[0], gamma, df, direction, eps0=1e-2, steps=4, f0=f0)
    assert t.min_rate > 1.9, t


def test_an_optimization_history_matches_the_direct_path(tmp_path):
    """14 MMA iterations over two continuation stages on the coarse mesh: the objective
    histories agree to 1e-4 relative (the iterative solves' tolerances carried through MMA)."""
    tiny = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.25", "optimizer.max_iter=14",
            "design.stage_iterations=6"]
    histories = []
    for name, extra in (("direct", []), ("iterative", ITERATIVE)):
        opt = Optimizer(tofsi.Problem(load("beam_in_channel_optimization", *tiny, *extra)), tmp_path / name)
        opt.run()
        histories.append(np.array([row.objective for row in opt.history]))
    direct, iterative = histories
    assert direct.size == iterative.size >= 10
    assert np.max(np.abs(iterative - direct) / np.abs(direct)) <= 1e-4


@pytest.mark.slow
def test_a_whole_optimization_ends_at_the_direct_paths_design(tmp_path):
    """60 MMA iterations over three continuation stages at 40 x 20: the final design within half
    of ``optimizer.tol_change`` (the change the optimizer stops on) of the direct path's, the
    final objective to 1e-4 (measured 2.8e-4 and 1.2e-5 at the adjoint's 3e-6)."""
    settings = [*COARSE, "optimizer.max_iter=60", "design.stage_iterations=20"]
    designs, objectives = [], []
    for name, extra in (("direct", []), ("iterative", ITERATIVE)):
        problem_ = tofsi.Problem(load("beam_in_channel_optimization", *settings, *extra))
        opt = Optimizer(problem_, tmp_path / name)
        opt.run()
        designs.append(np.load(tmp_path / name / "design.npy"))
        objectives.append(opt.history[-1].objective)
    assert len(opt.history) == 60
    assert np.max(np.abs(designs[1] - designs[0])) <= 0.5 * problem_.scene.optimizer.tol_change
    assert abs(objectives[1] - objectives[0]) <= 1e-4 * abs(objectives[0])
