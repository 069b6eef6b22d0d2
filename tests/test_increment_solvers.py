"""A mover in increments keeps its increments' factorizations across the moves at one design
(:class:`movers.increment_solvers.IncrementSolvers`).

Truths: a move preconditioned by the kept factors is the move solved to round-off (linear_tol 1e-15), to
the kept factors' tolerance; the store of a move's derivatives hands its factors over, after which a
nearby move (a Newton iterate's) factorizes nothing and makes its first increment's system (at the reference
mesh) no more; and its tangent is the fresh move's. A move on a problem with other fixed nodes, stiffening or
blend makes that system again and is the fresh move on that problem.
"""

import numpy as np
import pytest

import movers
from test_mover_derivatives import setup_problem

IN_INCREMENTS = {"spring": {"diagonals": "both"}, "linear": {}}


@pytest.mark.parametrize("name", sorted(IN_INCREMENTS))
def test_kept_factors_give_the_fresh_move_and_spare_the_later_moves_factorizations(name):
    mesh, problem, u = setup_problem(blended=True)
    mover = movers.create(name, increments=4, **IN_INCREMENTS[name])
    kept = mover.increment_solvers(problem)
    assert kept is not None and kept.rtol == 1e-13            # a thousandth of linear_tol
    first = mover.move(problem, u, solver=kept)
    assert first.report.factorizations >= 1 and first.report.converged
    mover.jvp(problem, first, np.ones_like(u))                # builds the store of its derivatives
    assert len(kept.factors) == 4                              # every increment's factors, kept
    nearby = u * (1 + 1e-4)                                    # a Newton step further
    again = mover.move(problem, nearby, solver=kept)
    fresh = movers.create(name, increments=4, linear_tol=1e-15, **IN_INCREMENTS[name]).move(problem, nearby)
    assert again.report.factorizations == 0 and fresh.report.factorizations >= 1   # teeth
    assert kept.reference.builds == 1        # the first increment's matrices and system: kept, not made again
    scale = np.abs(fresh.displacement).max()
    assert np.abs(again.displacement - fresh.displacement).max() <= 1e-12 * scale
    du = np.random.default_rng(3).normal(size=u.shape)
    du[problem.fixed_nodes] = 0.0
    t_again, t_fresh = mover.jvp(problem, again, du), mover.jvp(problem, fresh, du)
    assert np.abs(t_again - t_fresh).max() <= 1e-9 * np.abs(t_fresh).max()


def test_a_mover_without_kept_factors_and_an_iterative_tangent_keep_none():
    _, problem, _ = setup_problem(blended=False)
    assert movers.create("yeoh").increment_solvers(problem) is None
    assert movers.create("spring", increments=1, diagonals="both").increment_solvers(problem) is None
    assert movers.create("spring", increments=3, tangent_solver="amg").increment_solvers(problem) is None
    assert movers.create("linear", increments=1).increment_solvers(problem) is None


def other_problem(problem, change):
    """``problem`` with one input of its first increment's system changed."""
    from movers.problem import MotionProblem
    if change == "fixed nodes":                 # one more node held at rest
        free = np.setdiff1d(np.unique(problem.quads), problem.fixed_nodes)
        return MotionProblem(problem.points, problem.quads, np.append(problem.fixed_nodes, free[len(free) // 2]),
                             problem.stiffening, problem.grid, problem.blend)
    if change == "stiffening":
        return problem.with_data(stiffening=problem.stiffening ** 2)
    return problem.with_data(blend=0.5 * problem.blend)


@pytest.mark.parametrize("change, blended", [("fixed nodes", False), ("stiffening", False), ("blend", True)])
def test_the_kept_first_increment_is_made_again_when_an_input_changes(change, blended):
    """The first increment's kept matrices and system are keyed by every input: a bank passed to a
    move on the same mesh with other fixed nodes, stiffening or blend gives the fresh move on that
    problem, not the first problem's system (truth: a fresh mover solved to round-off)."""
    _, problem, u = setup_problem(blended=blended)
    mover = movers.create("spring", increments=4, diagonals="both")
    kept = mover.increment_solvers(problem)
    mover.move(problem, u, solver=kept)
    other = other_problem(problem, change)
    again = mover.move(other, u, solver=kept)
    fresh = movers.create("spring", increments=4, diagonals="both", linear_tol=1e-15).move(other, u)
    assert kept.reference.builds == 2
    scale = np.abs(fresh.displacement).max()
    assert np.abs(again.displacement - fresh.displacement).max() <= 1e-10 * scale
