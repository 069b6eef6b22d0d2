"""Mover derivatives for the adjoint: vector-Jacobian products against central differences.

The map is (prescribed motion u, stiffening factors f, blend s) -> mesh displacement x,
in the explicit-interface form (the inner block's nodes prescribed) and in the
density-blended form (every node blends mover and structure with its own s).
For random adjoint seeds ``xbar`` and directions:
``xbar . (x(u + h du) - x(u - h du)) / 2h == ubar . du``, likewise for ``f`` and ``s``.
Solves are run to round-off (``linear_tol = 1e-15`` forces factorizations),
so the remaining error is the O(h^2) of the differences.
"""

import numpy as np
import pytest

import movers
from movers.base import MotionProblem
from tofsi.mesh.structured import StructuredQuadMesh

CASES = [("yeoh", {"A20": 50.0, "kappa": 2.0, "newton_tol": 1e-13}),
         ("linear", {"increments": 1}),
         ("linear", {"increments": 3, "chi": 0.6}),
         ("spring", {"increments": 1, "diagonals": "1-3"}),
         ("spring", {"increments": 4, "diagonals": "both"}),
         ("spring", {"increments": 3, "diagonals": "selective"}),
         ("spring", {"increments": 4, "diagonals": "both", "scheme": "midpoint"}),
         ("spring", {"increments": 3, "diagonals": "selective", "scheme": "midpoint"}),
         ("spring", {"increments": 3, "diagonals": "both", "scheme": "midpoint", "first_increment": 0.1}),
         ("spring", {"increments": 3, "diagonals": "both", "first_increment": 0.2})]


def setup_problem(blended: bool):
    s = np.linspace(0, 1, 7)
    mesh = StructuredQuadMesh(s + 0.03 * np.sin(3 * s), s**1.1)
    rng = np.random.default_rng(11)
    boundary = np.unique(np.concatenate([mesh.side_nodes(k) for k in ("left", "right", "bottom", "top")]))
    inner = np.flatnonzero((np.abs(mesh.centroids - 0.5) < 0.18).all(axis=1))
    core = np.unique(mesh.quads[inner])
    c = mesh.points - 0.5
    u = 0.12 * np.column_stack([-c[:, 1], c[:, 0]]) + [0.03, -0.05]     # turn and shift
    if blended:
        moving = np.arange(mesh.n_elements)
        blend = rng.uniform(0.0, 0.9, mesh.n_nodes)
        blend[core] = 1.0
        u[boundary] = 0.0
        problem = MotionProblem.from_mesh(mesh, moving, boundary, 1.0 + rng.uniform(0, 1, len(moving)), blend)
    else:
        moving = np.setdiff1d(np.arange(mesh.n_elements), inner)
        problem = MotionProblem.from_mesh(mesh, moving, np.union1d(boundary, core),
                                          1.0 + rng.uniform(0, 1, len(moving)))
        u[np.setdiff1d(np.arange(mesh.n_nodes), core)] = 0.0
    return mesh, problem, u


@pytest.mark.parametrize("blended", [False, True], ids=["explicit", "blended"])
@pytest.mark.parametrize("name,params", CASES, ids=[f"{n}-{p}" for n, p in CASES])
def test_vjp_matches_central_differences(name, params, blended):
    mesh, problem, u = setup_problem(blended)
    mover = movers.create(name, linear_tol=1e-15, **params)
    result = mover.move(problem, u)
    rng = np.random.default_rng(12)
    xbar = rng.normal(size=(mesh.n_nodes, 2))
    ubar, fbar, sbar = mover.vjp(problem, result, xbar)
    free = np.setdiff1d(np.arange(mesh.n_nodes), problem.fixed_nodes)
    if not blended:
        assert np.all(ubar[free] == 0) and np.all(sbar == 0)
    h = 1e-6

    def fd(move_u=False, **change):
        plus = mover.move(problem.with_data(**{k: v[0] for k, v in change.items()}),
                          u + h * du if move_u else u).displacement
        minus = mover.move(problem.with_data(**{k: v[1] for k, v in change.items()}),
                           u - h * du if move_u else u).displacement
        return np.sum(xbar * (plus - minus)) / (2 * h)

    du = np.zeros_like(u)
    moved = np.arange(mesh.n_nodes) if blended else problem.fixed_nodes
    du[moved] = rng.normal(size=(moved.size, 2))
    du[problem.fixed_nodes] *= 0.0 if blended else 1.0           # the walls stay in the blended form
    assert np.sum(ubar * du) == pytest.approx(fd(move_u=True), rel=1e-7, abs=1e-10)
    df = rng.normal(size=len(problem.quads))
    f = problem.stiffening
    assert fbar @ df == pytest.approx(fd(stiffening=(f + h * df, f - h * df)), rel=1e-7, abs=1e-10)
    if blended:
        ds = rng.normal(size=mesh.n_nodes)
        s = problem.blend
        assert sbar @ ds == pytest.approx(fd(blend=(s + h * ds, s - h * ds)), rel=1e-7, abs=1e-10)


PATH_DEPENDENT = [c for c in CASES if c[1].get("increments", 1) > 1]


@pytest.mark.parametrize("blended", [False, True], ids=["explicit", "blended"])
@pytest.mark.parametrize("name,params", PATH_DEPENDENT, ids=[f"{n}-{p}" for n, p in PATH_DEPENDENT])
def test_jvp_matches_central_differences_and_the_vjp(name, params, blended):
    """The tangent sweep of a move in increments (a coupled Newton's ``dx/du``): against central
    differences of the move, and ``xbar . J du == (J^T xbar) . du`` with the reverse sweep to
    round-off (the two share each increment's factors, not their arithmetic)."""
    mesh, problem, u = setup_problem(blended)
    mover = movers.create(name, linear_tol=1e-15, **params)
    result = mover.move(problem, u)
    rng = np.random.default_rng(13)
    du = np.zeros_like(u)
    moved = np.setdiff1d(np.arange(mesh.n_nodes), problem.fixed_nodes) if blended else problem.fixed_nodes
    du[moved] = rng.normal(size=(moved.size, 2))
    x_dot = mover.jvp(problem, result, du)
    h = 1e-6
    fd = (mover.move(problem, u + h * du).displacement - mover.move(problem, u - h * du).displacement) / (2 * h)
    assert np.abs(x_dot - fd).max() <= 1e-7 * np.abs(fd).max()
    xbar = rng.normal(size=(mesh.n_nodes, 2))
    ubar = mover.vjp(problem, result, xbar)[0]
    assert np.sum(xbar * x_dot) == pytest.approx(np.sum(ubar * du), rel=1e-12)
    second = rng.normal(size=du.shape) * (du != 0)                 # linear in its input
    assert np.allclose(mover.jvp(problem, result, du + 2 * second),
                       x_dot + 2 * mover.jvp(problem, result, second), rtol=1e-12, atol=1e-15)
