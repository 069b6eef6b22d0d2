"""Stabilized Q1/Q1 flow against exact solutions: convergence rates and Poiseuille flow.

Expected rates for equal-order bilinear elements with PSPG (Hughes, Franca & Balestra 1986;
the viscous part of the strong residual dropped, as topFlow): velocity L2 2, H1 seminorm 1,
pressure L2 at least 1 (1.5-1.8 observed: the stabilized pressure superconverges on uniform
meshes). Taylor-Hood gives 3, 2, 2 on the same problems (tests/test_flow.py).
"""

import numpy as np
import pytest

from flow_cases import Manufactured, rates, unit_square
from tofsi.fem.geometry import map_points, physical_gradients
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.physics.flow import Flow
from tofsi.fields.flow import FluidSettings

PI = np.pi


def box(n, exact, density, symmetric=False, moved=False):
    """The manufactured flow on the unit square (closed box, the exact velocity on its sides),
    with the gradient or the strain-rate viscous form, on the reference or an ALE-moved mesh."""
    mesh, x = unit_square(n, moved)
    settings = FluidSettings(element="q1q1", density=density, viscosity=exact.mu, alpha_min=exact.alpha,
                             alpha_max=max(exact.alpha, 1.0),
                             outlet="traction-free" if symmetric else "zero-pressure")
    flow = Flow(mesh, settings, stokes=density == 0.0, boundary_velocity=exact.velocity, body_force=exact.force)
    w, _ = flow.solve(x=x)
    return w, flow.dofs, flow.corners(x)


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
    the inlet, where the dropped viscous term of the strong residual is not zero). The outlet
    is topFlow's: p = 0 and no tangential velocity."""
    mu, U, H, L = 0.7, 1.3, 1.0, 3.0
    velocity, drop, hs = [], [], []
    for n in (8, 16, 32):
        mesh = StructuredQuadMesh(np.linspace(0, L, 3 * n + 1), np.linspace(0, H, n + 1))
        settings = FluidSettings(element="q1q1", density=density, viscosity=mu, inlet_velocity=U,
                                 outlet="fixed-pressure", parallel_outflow=True)
        flow = Flow(mesh, settings, stokes=density == 0.0)
        w, _ = flow.solve()
        P, v = mesh.points, flow.corner_velocity(w)
        velocity.append(np.abs(v[:, 0] - 4 * U * P[:, 1] * (H - P[:, 1]) / H**2).max())
        drop.append(abs(flow.figures(w)["pressure_drop"] - 8 * mu * U * L / H**2))
        hs.append(1.0 / n)
    assert np.all(np.abs(rates(velocity, hs) - 2.0) < 0.05), velocity
    assert velocity[-1] < 3e-3 * U
    assert np.all(rates(drop, hs) > 1.0), drop
    assert drop[-1] < 0.015 * 8 * mu * U * L / H**2


def test_the_distributed_flow_refuses_the_equal_order_element_before_needing_petsc():
    """The PETSc slab assembly runs the Taylor-Hood kernel: a Q1/Q1 flow is refused by name (with or
    without petsc4py installed), not assembled with the wrong element."""
    from tofsi.core.errors import InputError
    from tofsi.parallel.flow_system import DistributedFlow
    mesh = StructuredQuadMesh(np.linspace(0, 2, 9), np.linspace(0, 1, 5))
    flow = Flow(mesh, FluidSettings(element="q1q1", outlet="zero-pressure"))
    with pytest.raises(InputError, match="fluid.element"):
        DistributedFlow(flow)
