"""Stabilized Q1/Q1 flow against exact solutions: convergence rates and Poiseuille flow.

Expected rates for equal-order bilinear elements with PSPG (Hughes, Franca & Balestra 1986;
the viscous part of the strong residual dropped, as topFlow): velocity L2 2, H1 seminorm 1,
pressure L2 at least 1 (1.5-1.8 observed: the stabilized pressure superconverges on uniform
meshes). Taylor-Hood gives 3, 2, 2 on the same problems (tests/test_flow.py).
"""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from flow_cases import Manufactured, rates
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.fem.geometry import map_points, physical_gradients
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions
from tofsi.mesh import StructuredQuadMesh
from tofsi.physics.fluid_elements import EqualOrder

PI = np.pi


def solve(mesh, fixed_velocity, values, alpha, density, mu, symmetric=False, x=None, force=None, pin=None):
    """Newton on the Q1/Q1 system: velocity dofs ``fixed_velocity`` held at ``values`` (3n,),
    pressure dofs ``pin`` (node indices) held at their ``values``."""
    n = mesh.n_nodes
    dofs = np.hstack([element_dofs(mesh.quads, 2), 2 * n + mesh.quads])
    P = mesh.points if x is None else mesh.points + x
    Xe = P[mesh.quads]
    f = None if force is None else force(map_points(Xe, EqualOrder.POINTS))
    bc = DirichletOperator(dofs, dofs, 3 * n, np.concatenate([fixed_velocity, 2 * n + np.asarray(pin)]))
    w = np.where(bc.is_fixed, values, 0.0)
    a = np.full(mesh.n_elements, float(alpha))
    for _ in range(20):
        we = w[dofs]
        Re, Ke = EqualOrder.residual(Xe, we[:, :8].reshape(-1, 4, 2), we[:, 8:], a, density, mu, symmetric, f)
        R = bc.homogenize(assemble_vector(dofs, Re, 3 * n))
        if np.linalg.norm(R) < 1e-11 * max(1.0, np.abs(Re).max()):
            return w, dofs, Xe
        w = w + spla.spsolve(bc.matrix(Ke).tocsc(), -R)
    raise AssertionError(f"no convergence: |R| = {np.linalg.norm(R):.3e}")


def box(n, exact, density, symmetric=False, moved=False):
    mesh = StructuredQuadMesh(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    x = None
    if moved:                                          # a smooth interior motion; the boundary stays
        X = mesh.points
        bump = np.sin(PI * X[:, 0]) * np.sin(PI * X[:, 1])
        x = 0.08 * np.column_stack([bump * np.cos(2 * X[:, 1]), 0.6 * bump * np.sin(3 * X[:, 0])])
    sides = mesh.boundary_nodes
    values = np.zeros(3 * mesh.n_nodes)
    values[:2 * mesh.n_nodes].reshape(-1, 2)[sides] = exact.velocity(mesh.points[sides])
    values[2 * mesh.n_nodes] = exact.pressure(mesh.points[0])
    fixed = np.concatenate([2 * sides, 2 * sides + 1])
    return solve(mesh, fixed, values, exact.alpha, density, exact.mu, symmetric, x, exact.force, pin=[0])


def errors(w, dofs, Xe, exact):
    """(velocity L2, velocity H1 seminorm, pressure L2 up to a constant), 5x5 Gauss."""
    pts, wts = gauss_square(5)
    N, _ = shape_functions(1, pts)
    grad, det = physical_gradients(Xe, 1, pts)
    we = w[dofs]
    ve, pe = we[:, :8].reshape(-1, 4, 2), we[:, 8:]
    P, W = map_points(Xe, pts), det * wts
    vh, ph = np.matmul(N, ve), np.matmul(pe, N.T)
    Lh = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)
    p = exact.pressure(P)
    dp = (ph - np.sum(W * ph) / W.sum()) - (p - np.sum(W * p) / W.sum())
    return (np.sqrt(np.sum(W[..., None] * (vh - exact.velocity(P)) ** 2)),
            np.sqrt(np.sum(W[..., None, None] * (Lh - exact.gradient(P)) ** 2)),
            np.sqrt(np.sum(W * dp**2)))


def assert_q1q1_rates(errs, hs):
    e = np.array(errs)
    r = [rates(c, hs) for c in e.T]
    assert np.all(np.abs(r[0] - 2.0) < 0.15), (e, r)           # velocity L2
    assert np.all(np.abs(r[1] - 1.0) < 0.1), (e, r)            # velocity H1
    assert np.all((r[2] > 1.0) & (r[2] < 2.0)), (e, r)         # pressure L2


@pytest.mark.parametrize("symmetric, moved", [(False, False), (True, True)], ids=["gradient form", "symmetric, ALE-moved"])
def test_stokes_brinkman_manufactured_solution_converges_at_q1q1_rates(symmetric, moved):
    exact = Manufactured(mu=0.8, rho=0.0, alpha=3.0)
    errs, hs = [], []
    for n in (16, 32, 64):
        errs.append(errors(*box(n, exact, 0.0, symmetric, moved), exact))
        hs.append(1.0 / n)
    assert_q1q1_rates(errs, hs)


def test_navier_stokes_manufactured_solution_converges_at_q1q1_rates():
    exact = Manufactured(mu=0.05, rho=1.0)
    errs, hs = [], []
    for n in (16, 32, 64):
        errs.append(errors(*box(n, exact, 1.0), exact))
        hs.append(1.0 / n)
    assert_q1q1_rates(errs, hs)


@pytest.mark.parametrize("density", [0.0, 2.0])
def test_poiseuille_flow_converges_at_second_order(density):
    """A parabola is not in the Q1 space, so unlike Taylor-Hood Q1/Q1 is not exact: the nodal
    velocity converges at rate 2 and the pressure drop at rate >= 1 (PSPG's inconsistency at
    the inlet, where the dropped viscous term of the strong residual is not zero)."""
    mu, U, H, L = 0.7, 1.3, 1.0, 3.0
    velocity, drop, hs = [], [], []
    for n in (8, 16, 32):
        mesh = StructuredQuadMesh(np.linspace(0, L, 3 * n + 1), np.linspace(0, H, n + 1))
        N, P = mesh.n_nodes, mesh.points
        left, right = mesh.side_nodes("left"), mesh.side_nodes("right")
        walls = np.concatenate([left, mesh.side_nodes("bottom"), mesh.side_nodes("top")])
        values = np.zeros(3 * N)
        values[2 * left] = 4 * U * P[left, 1] * (H - P[left, 1]) / H**2
        fixed = np.concatenate([2 * walls, 2 * walls + 1, 2 * right + 1])   # outlet: v_y = 0, p = 0
        w, _, _ = solve(mesh, fixed, values, 0.0, density, mu, pin=right)
        v = w[:2 * N].reshape(-1, 2)
        velocity.append(np.abs(v[:, 0] - 4 * U * P[:, 1] * (H - P[:, 1]) / H**2).max())
        drop.append(abs(w[2 * N + left].mean() - 8 * mu * U * L / H**2))
        hs.append(1.0 / n)
    assert np.all(np.abs(rates(velocity, hs) - 2.0) < 0.05), velocity
    assert velocity[-1] < 3e-3 * U
    assert np.all(rates(drop, hs) > 1.0), drop
    assert drop[-1] < 0.015 * 8 * mu * U * L / H**2
