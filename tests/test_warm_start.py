"""Warm starts and recycled solvers of the Yeoh mover: faster, never different.

Truths: the cold solve from zero (load steps) for the equilibrium -- a warm
start must land on it to the Newton tolerance --, central differences for
the vector-Jacobian product at a warm-started equilibrium, and iteration and
factorization counts for "faster".
"""

import numpy as np
import pytest

import movers
from test_coupled import soft_model
from test_mover_derivatives import setup_problem
from tofsi.mesh import quality
from tofsi.coupling.motion import motion_setup

from conftest import load


def foil(degrees: float):
    scene = load("foil_in_channel", "mover.name=yeoh", "deformation.mode=rotation",
                 f"deformation.rotation_deg={degrees}")
    setup = motion_setup(scene)
    return setup.motion, setup.prescribed


@pytest.fixture(scope="module")
def eight_degrees():
    motion, prescribed = foil(8.0)
    return motion.move(prescribed)


def relative(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_a_warm_start_lands_on_the_cold_equilibrium_in_fewer_steps(eight_degrees):
    motion, prescribed = foil(9.0)
    cold = motion.move(prescribed)
    warm = motion.move(prescribed, initial=eight_degrees.displacement)
    assert warm.report.warm_start and not cold.report.warm_start
    assert warm.report.increments == 1 and warm.report.cutbacks == 0
    assert warm.report.newton_iterations <= cold.report.newton_iterations - 3, (warm.report, cold.report)
    assert relative(warm.displacement, cold.displacement) <= 1e-8


def test_an_initial_farther_than_zero_or_inverting_falls_back_to_load_steps(eight_degrees):
    motion, prescribed = foil(9.0)
    cold = motion.move(prescribed)
    far = motion.move(prescribed, initial=3.0 * eight_degrees.displacement)    # farther than zero
    assert not far.report.warm_start
    np.testing.assert_array_equal(far.displacement, cold.displacement)          # the same path exactly
    wild = eight_degrees.displacement.copy()
    wild[motion.follows] = motion.target(prescribed)[motion.follows]           # prescribed values in place,
    wild[np.setdiff1d(np.arange(len(wild)), motion.base.fixed_nodes)] = 0.0    # free nodes left behind
    assert quality.inverted(motion.mesh.points + wild, motion.base.quads).any()
    inverted = motion.move(prescribed, initial=wild)
    assert not inverted.report.warm_start and inverted.report.converged
    assert relative(inverted.displacement, cold.displacement) <= 1e-8


def test_a_recycled_solver_gives_the_same_equilibrium_without_refactorizing(eight_degrees):
    motion, prescribed = foil(8.2)
    cold = motion.move(prescribed)
    again = motion.move(prescribed, initial=eight_degrees.displacement, solver=eight_degrees.solver)
    assert again.report.factorizations < cold.report.factorizations
    assert again.report.factorizations <= 1
    assert relative(again.displacement, cold.displacement) <= 1e-8


@pytest.mark.parametrize("blended", [False, True], ids=["explicit", "blended"])
def test_vjp_of_the_warm_started_map_matches_central_differences(blended):
    """The map's derivative where every move (the base and the differences) starts from a
    nearby solution, as inside an optimization: the implicit-function adjoint at the
    returned equilibrium is exact."""
    mesh, problem, u = setup_problem(blended)
    mover = movers.create("yeoh", A20=50.0, kappa=2.0, newton_tol=1e-13, linear_tol=1e-15)
    start = mover.move(problem, 0.9 * u).displacement
    result = mover.move(problem, u, initial=start)
    assert result.report.warm_start
    rng = np.random.default_rng(21)
    xbar = rng.normal(size=(mesh.n_nodes, 2))
    ubar, fbar, _ = mover.vjp(problem, result, xbar)
    h = 1e-6
    du = np.zeros_like(u)
    moved = np.arange(mesh.n_nodes) if blended else problem.fixed_nodes
    du[moved] = rng.normal(size=(moved.size, 2))
    du[problem.fixed_nodes] *= 0.0 if blended else 1.0
    plus = mover.move(problem, u + h * du, initial=start).displacement
    minus = mover.move(problem, u - h * du, initial=start).displacement
    assert np.sum(ubar * du) == pytest.approx(np.sum(xbar * (plus - minus)) / (2 * h), rel=1e-7, abs=1e-10)
    df = rng.normal(size=len(problem.quads))
    f = problem.stiffening
    plus = mover.move(problem.with_data(stiffening=f + h * df), u, initial=start).displacement
    minus = mover.move(problem.with_data(stiffening=f - h * df), u, initial=start).displacement
    assert fbar @ df == pytest.approx(np.sum(xbar * (plus - minus)) / (2 * h), rel=1e-7, abs=1e-10)


def test_partitioned_coupling_warm_starts_the_mover_and_changes_nothing():
    """Each coupling sweep's move starts from the last sweep's mesh with its solver; a solve
    warm-started from a nearby design's state lands on the cold solve's state."""
    model, rho = soft_model("partitioned")
    state = model.solve(rho)
    mover = state.reports["mover"]
    assert mover["warm_start"] and mover["factorizations"] == 0     # the last sweep: recycled
    design = model.design_elements
    nearby = rho.copy()
    nearby[design] = np.clip(rho[design] + 0.05 * (model.mesh.centroids[design, 0] > 1.0), 0, 1)
    warm = model.solve(nearby, guess=state)
    cold = model.solve(nearby)
    for f in ("u", "x", "w"):
        assert relative(getattr(warm, f), getattr(cold, f)) <= 1e-8, f
