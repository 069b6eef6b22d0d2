"""Taylor-Hood flow: exact Poiseuille, convergence rates, Brinkman, Jacobian blocks."""

import numpy as np
import pytest

from flow_cases import Kovasznay, Manufactured, errors, rates, unit_square
from tofsi.core.errors import NumericalError
from tofsi.mesh.grading import graded_axis
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.physics.flow import Flow
from tofsi.fields.flow import FluidSettings


def graded_channel():
    xs = graded_axis(3.0, [1.0, 1.3], [(1.0, 1.3)], 0.05, 0.3, 1.3)
    ys = graded_axis(1.0, [0.4], [(0.4, 0.45)], 0.03, 0.2, 1.4)
    return StructuredQuadMesh(xs, ys)


@pytest.mark.parametrize("stokes", [True, False])
def test_poiseuille_is_exact_on_a_graded_mesh(stokes):
    mesh = graded_channel()
    mu, U, H, L = 0.7, 1.3, 1.0, 3.0
    flow = Flow(mesh, FluidSettings(density=2.0, viscosity=mu, inlet_velocity=U), stokes=stokes)
    w, report = flow.solve()
    assert report.converged
    y = mesh.points9()[:, 1]
    v = w[:flow.n_velocity].reshape(-1, 2)
    np.testing.assert_allclose(v[:, 0], 4 * U * y * (H - y) / H**2, rtol=0, atol=1e-10)
    np.testing.assert_allclose(v[:, 1], 0.0, atol=1e-10)
    dpdx = -8 * mu * U / H**2
    p = w[flow.n_velocity:]
    np.testing.assert_allclose(p, dpdx * (mesh.points[:, 0] - L), atol=1e-10 * 8 * mu * U * L)
    figs = flow.figures(w)
    assert figs["pressure_drop"] == pytest.approx(-dpdx * L, rel=1e-12)
    assert figs["viscous_dissipation"] == pytest.approx(mu * L * 16 * U**2 / (3 * H), rel=1e-12)


PI = np.pi


@pytest.mark.parametrize("moved", [False, True], ids=["fixed mesh", "ALE-moved mesh"])
def test_manufactured_solution_converges_at_taylor_hood_rates(moved):
    exact = Manufactured(mu=0.8, rho=0.0, alpha=3.0)
    errs, hs = [], []
    for n in (32, 64, 128):                   # the pressure superconverges on coarser meshes
        mesh, x = unit_square(n, moved)
        settings = FluidSettings(density=0.0, viscosity=exact.mu, alpha_min=exact.alpha,
                                 alpha_max=exact.alpha)
        flow = Flow(mesh, settings, stokes=True, boundary_velocity=exact.velocity,
                    body_force=exact.force)
        w, _ = flow.solve(x=x)
        errs.append(errors(flow, w, exact, x))
        hs.append(1.0 / n)
    e = np.array(errs)
    for column, expected in zip(e.T, (3.0, 2.0, 2.0), strict=True):       # velocity L2, H1, pressure L2
        assert np.all(np.abs(rates(column, hs) - expected) < 0.1), (e, rates(column, hs))


def test_navier_stokes_manufactured_solution_converges():
    exact = Manufactured(mu=0.05, rho=1.0)
    errs, hs = [], []
    for n in (16, 32, 64):
        mesh, x = unit_square(n)
        flow = Flow(mesh, FluidSettings(density=1.0, viscosity=exact.mu), boundary_velocity=exact.velocity,
                    body_force=exact.force)
        w, report = flow.solve()
        assert report.newton_iterations >= 2
        errs.append(errors(flow, w, exact))
        hs.append(1.0 / n)
    for column, expected in zip(np.array(errs).T, (3.0, 2.0, 2.0), strict=True):
        assert np.all(np.abs(rates(column, hs) - expected) < 0.1)


def test_kovasznay_flow_converges_at_the_expected_rates():
    exact = Kovasznay(Re=40.0)
    errs, hs = [], []
    for k in (4, 8, 16):
        mesh = StructuredQuadMesh(np.linspace(-0.5, 1.0, 3 * k + 1), np.linspace(-0.5, 1.5, 4 * k + 1))
        flow = Flow(mesh, FluidSettings(density=1.0, viscosity=1 / 40.0), boundary_velocity=exact.velocity)
        w, report = flow.solve()
        assert report.converged
        errs.append(errors(flow, w, exact))
        hs.append(0.5 / k)
    e = np.array(errs)
    for column, expected in zip(e.T, (3.0, 2.0, 2.0), strict=True):
        assert np.all(np.abs(rates(column, hs) - expected) < 0.1), (e, rates(column, hs))


def block_channel(alpha_max, density=1.0):
    mesh = StructuredQuadMesh(np.linspace(0, 2, 41), np.linspace(0, 1, 21))
    c = mesh.centroids
    rho = ((np.abs(c[:, 0] - 1.0) < 0.2) & (np.abs(c[:, 1] - 0.5) < 0.2)).astype(float)
    flow = Flow(mesh, FluidSettings(density=density, alpha_max=alpha_max))
    return mesh, flow, rho


def solid_interior_speed(mesh, flow, w, rho, depth):
    """Largest speed at Q2 nodes all of whose elements are solid and ``depth`` layers deep."""
    from tofsi.mesh.layers import element_layers
    solid = rho >= 1
    boundary = np.unique(mesh.quads[~solid])
    layer = element_layers(mesh.incidence, boundary, solid)
    out = np.zeros(mesh.n_nodes9, bool)
    out[mesh.quads9[~solid | (layer < depth)].ravel()] = True
    return np.abs(w[:flow.n_velocity].reshape(-1, 2)[~out]).max()


@pytest.mark.parametrize("alpha_max", [1e2, 1e4, 1e6, 1e8, 1e10])
def test_brinkman_block_converges_without_nan_for_any_friction(alpha_max):
    mesh, flow, rho = block_channel(alpha_max)
    w, report = flow.solve(rho=rho)
    assert report.converged and np.all(np.isfinite(w))
    assert np.isfinite(flow.figures(w, rho=rho)["dissipated_power"])


def test_flow_inside_the_block_obeys_darcy_one_over_alpha():
    """Deep in the block the momentum balance is Darcy's, alpha v = -grad p: |v| ~ 1/alpha."""
    speeds = []
    for alpha_max in (1e6, 1e8):
        mesh, flow, rho = block_channel(alpha_max)
        w, _ = flow.solve(rho=rho)
        speeds.append(solid_interior_speed(mesh, flow, w, rho, depth=2))
    assert speeds[0] / speeds[1] == pytest.approx(100.0, rel=0.05)


def test_velocity_inside_the_beam_is_below_a_millionth_of_the_inflow():
    """alpha_max = 1e9 (TOFLUX's value): the beam's interior is still to 1e-6 of the inflow.

    (At alpha_max = 1e8 the interior speed is about 6e-6: Darcy leakage |grad p| / alpha
    driven by the beam's pressure difference, not an error.)
    """
    import dataclasses
    import tofsi
    from tofsi.mesh.channel import build_mesh
    from tofsi.mesh.structured import SOLID
    from conftest import scene_path
    scene = tofsi.load_scene(scene_path("beam_in_channel"))
    mesh = build_mesh(scene.geometry, scene.mesh)
    rho = (mesh.region == SOLID).astype(float)
    flow = Flow(mesh, dataclasses.replace(scene.fluid, alpha_max=1e9))
    w, _ = flow.solve(rho=rho)
    assert solid_interior_speed(mesh, flow, w, rho, depth=3) < 1e-6 * scene.fluid.inlet_velocity


def _random_state(flow, mesh, rng):
    w = rng.normal(size=flow.size)
    X = mesh.points
    x = 0.02 * np.column_stack([np.sin(3 * X[:, 0] + X[:, 1]), np.cos(2 * X[:, 1] - X[:, 0])])
    rho = rng.uniform(0.05, 0.95, mesh.n_elements)
    return w, x, rho


@pytest.mark.parametrize("outlet", ["zero-pressure", "traction-free"])
def test_fluid_jacobian_blocks_match_central_differences(outlet):
    rng = np.random.default_rng(21)
    mesh = StructuredQuadMesh(np.array([0, 0.3, 0.7, 1.2]), np.array([0, 0.4, 1.0]))
    flow = Flow(mesh, FluidSettings(density=1.7, viscosity=0.3, alpha_max=50.0, outlet=outlet))
    w, x, rho = _random_state(flow, mesh, rng)
    R = lambda w_, x_=x, r_=rho: flow.residual(w_, x_, r_)
    Ke = flow.element_jacobians(w, x, rho)[1]
    from tofsi.fem.assembly import SparsePattern
    Fw = SparsePattern(flow.dofs, flow.dofs, (flow.size, flow.size)).assemble(Ke)
    h = 1e-6
    for _ in range(3):
        d = rng.normal(size=flow.size)
        fd = (R(w + h * d) - R(w - h * d)) / (2 * h)
        assert np.linalg.norm(Fw @ d - fd) <= 1e-6 * np.linalg.norm(fd)
        dx = rng.normal(size=(mesh.n_nodes, 2))
        fd = (R(w, x + h * dx) - R(w, x - h * dx)) / (2 * h)
        assert np.linalg.norm(flow.shape_partial(w, x, rho) @ dx.ravel() - fd) <= 1e-6 * np.linalg.norm(fd)
        dr = rng.normal(size=mesh.n_elements)
        fd = (R(w, x, rho + h * dr) - R(w, x, rho - h * dr)) / (2 * h)
        assert np.linalg.norm(flow.density_partial(w, x, rho) @ dr - fd) <= 1e-6 * np.linalg.norm(fd)


def test_reynolds_continuation_rescues_a_failing_newton_solve():
    def solve(steps):
        mesh, flow, rho = block_channel(1e4, density=400.0)
        flow.settings = FluidSettings(density=400.0, alpha_max=1e4, newton_max_iter=6,
                                      continuation_steps=steps)
        return flow.solve(rho=rho)
    with pytest.raises(NumericalError) as err:
        solve(1)
    assert err.value.diagnostic["history"]
    w, report = solve(10)
    assert report.converged and report.continuation[-1] == 400.0 and np.all(np.isfinite(w))


def test_closed_cavity_pressure_is_fixed_up_to_the_pinned_constant():
    mesh = StructuredQuadMesh(np.linspace(0, 1, 11), np.linspace(0, 1, 11))

    def lid(P):
        v = np.zeros_like(P)
        v[:, 0] = np.where(P[:, 1] > 1 - 1e-12, 16 * P[:, 0] ** 2 * (1 - P[:, 0]) ** 2, 0.0)
        return v
    flow = Flow(mesh, FluidSettings(density=1.0), boundary_velocity=lid)
    w, report = flow.solve()
    assert report.converged and np.all(np.isfinite(w))
    r = flow.residual(w)
    assert np.abs(r[~flow.bc.is_fixed]).max() < 1e-10       # every free equation holds
    assert w[flow.n_velocity] == 0.0                           # the pinned pressure


def test_the_chunked_kernel_gives_the_one_call_values_bitwise():
    """fluid_elements in chunks of 7 against one fluid_element call on 40 elements (and complex
    inputs, as the complex step uses): identical residuals and Jacobians."""
    from tofsi.physics.fluid_kernel import fluid_element, fluid_elements
    rng = np.random.default_rng(4)
    mesh = StructuredQuadMesh(np.linspace(0, 2, 9), np.linspace(0, 1, 6))
    flow = Flow(mesh, FluidSettings(density=1.0, viscosity=0.1))
    w = rng.standard_normal(flow.size)
    ve, pe = flow.split(w)
    Xe = flow.corners() + 0.01j * rng.standard_normal((mesh.n_elements, 4, 2))
    alpha = rng.uniform(0, 100, mesh.n_elements)
    for jacobian in (True, False):
        whole = fluid_element(Xe, ve, pe, alpha, 1.0, 0.1, False, jacobian)
        chunked = fluid_elements(Xe, ve, pe, alpha, 1.0, 0.1, False, jacobian, chunk=7)
        assert np.array_equal(whole[0], chunked[0])
        assert (whole[1] is None and chunked[1] is None) or np.array_equal(whole[1], chunked[1])


@pytest.mark.parametrize("symmetric", [False, True])
@pytest.mark.parametrize("density", [0.0, 1.3])
def test_the_element_layout_kernel_equals_the_block_by_block_kernel(symmetric, density):
    """The kernel that builds the velocity block in the element matrix's layout against the
    block-by-block formulation (residuals and Jacobians, real and complex-step corners)."""
    from fluid_kernel_by_blocks import fluid_element_by_blocks
    from tofsi.physics.fluid_kernel import fluid_element
    rng = np.random.default_rng(5)
    E = 50
    Xe = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)[None] * 0.1 + 0.02 * rng.random((E, 4, 2))
    ve, pe, alpha = rng.normal(size=(E, 9, 2)), rng.normal(size=(E, 4)), 1e3 * rng.random(E)
    for X in (Xe, Xe + 1e-30j * rng.random((E, 4, 2))):
        R, K = fluid_element(X, ve, pe, alpha, density, 0.7, symmetric)
        R0, K0 = fluid_element_by_blocks(X, ve, pe, alpha, density, 0.7, symmetric)
        np.testing.assert_allclose(R, R0, rtol=0, atol=1e-13 * np.abs(R0).max())
        np.testing.assert_allclose(K, K0, rtol=0, atol=1e-13 * np.abs(K0).max())
        np.testing.assert_allclose(K.imag, K0.imag, rtol=0, atol=1e-13 * max(np.abs(K0.imag).max(), 1e-300))
