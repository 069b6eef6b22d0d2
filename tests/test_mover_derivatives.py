"""Mover derivatives for the adjoint: vector-Jacobian products against central differences.

The map is (prescribed motion u_p, stiffening factors f) -> mesh displacement x.
For random adjoint seeds ``xbar`` and directions ``du``, ``df``:
``xbar . (x(u + h du) - x(u - h du)) / 2h == ubar . du`` and likewise for ``f``.
Solves are run to round-off (``linear_tol = 1e-15`` forces factorizations),
so the remaining error is the O(h^2) of the differences.
"""

import numpy as np
import pytest

import movers
from movers.base import MotionProblem
from tofsi.mesh import StructuredQuadMesh

CASES = [("yeoh", {"A20": 50.0, "kappa": 2.0}),
         ("linear", {"increments": 1}),
         ("linear", {"increments": 3, "chi": 0.6}),
         ("spring", {"increments": 1, "diagonals": "1-3"}),
         ("spring", {"increments": 4, "diagonals": "both"}),
         ("spring", {"increments": 3, "diagonals": "selective"})]


def setup_problem():
    s = np.linspace(0, 1, 7)
    mesh = StructuredQuadMesh(s + 0.03 * np.sin(3 * s), s**1.1)
    inner = np.flatnonzero((np.abs(mesh.centroids - 0.5) < 0.18).all(axis=1))
    moving = np.setdiff1d(np.arange(mesh.n_elements), inner)
    boundary = np.unique(np.concatenate([mesh.side_nodes(k) for k in ("left", "right", "bottom", "top")]))
    fixed = np.union1d(boundary, np.unique(mesh.quads[inner]))
    rng = np.random.default_rng(11)
    f = 1.0 + rng.uniform(0, 1, len(moving))
    problem = MotionProblem.from_mesh(mesh, moving, fixed, f)
    u = np.zeros((mesh.n_nodes, 2))
    core = np.unique(mesh.quads[inner])
    c = mesh.points[core] - 0.5
    u[core] = 0.12 * np.column_stack([-c[:, 1], c[:, 0]]) + [0.03, -0.05]    # turn and shift
    return mesh, problem, u


def with_stiffening(problem, f):
    return MotionProblem(problem.points, problem.quads, problem.fixed_nodes, f, problem.grid)


@pytest.mark.parametrize("name,params", CASES, ids=[f"{n}-{p}" for n, p in CASES])
def test_vjp_matches_central_differences(name, params):
    mesh, problem, u = setup_problem()
    mover = movers.create(name, linear_tol=1e-15, **params)
    result = mover.move(problem, u)
    rng = np.random.default_rng(12)
    xbar = rng.normal(size=(mesh.n_nodes, 2))
    ubar, fbar = mover.vjp(problem, result, xbar)
    assert np.all(ubar[np.setdiff1d(np.arange(mesh.n_nodes), problem.fixed_nodes)] == 0)

    du = np.zeros_like(u)
    du[problem.fixed_nodes] = rng.normal(size=(problem.fixed_nodes.size, 2))
    h = 1e-6
    fd = np.sum(xbar * (mover.move(problem, u + h * du).displacement
                        - mover.move(problem, u - h * du).displacement)) / (2 * h)
    assert np.sum(ubar * du) == pytest.approx(fd, rel=1e-7, abs=1e-10)

    df = rng.normal(size=len(problem.quads))
    fd = np.sum(xbar * (mover.move(with_stiffening(problem, problem.stiffening + h * df), u).displacement
                        - mover.move(with_stiffening(problem, problem.stiffening - h * df), u).displacement)) / (2 * h)
    assert fbar @ df == pytest.approx(fd, rel=1e-7, abs=1e-10)
