"""Structure block: patch test, the fluid load against exact resultants, S blocks by differences."""

import numpy as np
import pytest

from tofsi.fem.assembly import element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.linalg import DirectSolver
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.physics.flow import Flow
from tofsi.physics.structure import Structure
from tofsi.fields.flow import FluidSettings
from tofsi.fields.structure import StructureSettings


def distorted(n=5, amp=0.12, seed=0):
    mesh = StructuredQuadMesh(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    rng = np.random.default_rng(seed)
    boundary = np.unique(np.concatenate([mesh.side_nodes(s) for s in ("left", "right", "bottom", "top")]))
    x = amp / n * rng.uniform(-1, 1, mesh.points.shape)
    x[boundary] = 0.0
    return mesh, x, boundary


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.49])
def test_q1_patch_test_on_distorted_quads(nu):
    mesh, x, boundary = distorted()
    P = mesh.points + x
    A, b = np.array([[0.3, -0.7], [1.1, 0.2]]), np.array([0.05, -0.02])
    exact = P @ A.T + b
    dofs = element_dofs(mesh.quads, 2)
    Ke = element_stiffness(P[mesh.quads], *lame(2.0, nu))
    fixed = element_dofs(boundary[:, None], 2).ravel()
    bc = DirichletOperator(dofs, dofs, 2 * mesh.n_nodes, fixed)
    rhs = np.zeros(2 * mesh.n_nodes)
    rhs[fixed] = exact.ravel()[fixed]
    K_full = DirichletOperator(dofs, dofs, 2 * mesh.n_nodes, np.zeros(0, int)).matrix(Ke)
    rhs -= bc.homogenize(K_full @ rhs)
    u = DirectSolver(bc.matrix(Ke)).solve(rhs)
    np.testing.assert_allclose(u, exact.ravel(), atol=1e-12)


def polynomial_state(flow, mesh, x, a=0.7, b=-1.3, c=2.1, d=0.4):
    """v = (a y^2, b x^2) on the Q2 nodes, p = c x + d y on the corners (current positions)."""
    P9 = mesh.points9(mesh.points + x)
    P1 = mesh.points + x
    w = np.zeros(flow.size)
    w[:flow.n_velocity] = np.column_stack([a * P9[:, 1] ** 2, b * P9[:, 0] ** 2]).ravel()
    w[flow.n_velocity:] = c * P1[:, 0] + d * P1[:, 1]
    return w


def test_stress_divergence_load_resultant_and_moment_are_exact_on_a_distorted_block():
    """For a polynomial flow, sum of nodal loads = int div sigma over the solid block (exact)."""
    mesh, x, _ = distorted(6, amp=0.1, seed=3)
    mu = 0.9
    flow = Flow(mesh, FluidSettings(viscosity=mu))
    structure = Structure(mesh, StructureSettings(load="stress-divergence"), flow)
    a, b, c, d = 0.7, -1.3, 2.1, 0.4
    w = polynomial_state(flow, mesh, x, a, b, c, d)
    rho = np.zeros(mesh.n_elements)
    block = (np.abs(mesh.centroids - 0.5) < 0.25).all(axis=1)     # 3x3 elements, moved
    rho[block] = 1.0
    f = structure.load(w, x, rho).reshape(-1, 2)
    from tofsi.mesh.quality import signed_area
    area = signed_area(mesh.points + x, mesh.quads[block]).sum()
    div = np.array([-c + 2 * a * mu, 2 * b * mu - d])               # div sigma, constant here
    np.testing.assert_allclose(f.sum(axis=0), area * div, rtol=1e-12, atol=1e-13)
    # moment about the origin: int (x div_y - y div_x) over the block (sigma is symmetric)
    P = mesh.points + x
    from tofsi.fem.geometry import map_points, physical_gradients
    from tofsi.fem.quadrature import gauss_square
    pts, wts = gauss_square(3)
    Xe = P[mesh.quads[block]]
    _, det = physical_gradients(Xe, 1, pts)
    Q = map_points(Xe, pts)
    moment = np.sum((Q[..., 0] * div[1] - Q[..., 1] * div[0]) * det * wts)
    assert np.sum(P[:, 0] * f[:, 1] - P[:, 1] * f[:, 0]) == pytest.approx(moment, rel=1e-12, abs=1e-13)


def test_reaction_load_resultant_is_the_brinkman_exchange_on_a_distorted_block():
    """The reaction on a solid block away from Dirichlet rows is its residual tested with the Q1
    shape functions, which sum to one: the viscous and pressure terms cancel and the resultant
    is ``int_block (alpha_max - alpha_min) v_h + rho_f (grad v_h) v_h`` (v_h the Q2 field)."""
    mesh, x, _ = distorted(6, amp=0.1, seed=3)
    flow = Flow(mesh, FluidSettings(viscosity=0.9, density=1.3, alpha_max=70.0, alpha_min=2.0))
    structure = Structure(mesh, StructureSettings(), flow)
    w = polynomial_state(flow, mesh, x)
    rho = np.zeros(mesh.n_elements)
    block = (np.abs(mesh.centroids - 0.5) < 0.25).all(axis=1)
    rho[block] = 1.0
    f = structure.load(w, x, rho).reshape(-1, 2)
    from tofsi.fem.geometry import physical_gradients
    from tofsi.fem.quadrature import gauss_square
    from tofsi.fem.shapes import shape_functions
    pts, wts = gauss_square(3)
    Xe = (mesh.points + x)[mesh.quads[block]]
    grad, det = physical_gradients(Xe, 2, pts)                     # Q2 gradients (E, G, 9, 2)
    N, _ = shape_functions(2, pts)
    ve = w[flow.dofs[block, :18]].reshape(-1, 9, 2)
    v = np.matmul(N, ve)                                           # (E, G, 2)
    L = np.einsum("eai,egaj->egij", ve, grad)                      # dv_i/dx_j
    integrand = (70.0 - 2.0) * v + 1.3 * np.einsum("egij,egj->egi", L, v)
    exchange = np.sum(integrand * (det * wts)[..., None], axis=(0, 1))
    np.testing.assert_allclose(f.sum(axis=0), exchange, rtol=1e-12)
    assert structure.force.resultant(w, x, rho) == pytest.approx(tuple(f.sum(axis=0)), rel=1e-14)
    assert np.all(f[np.setdiff1d(np.arange(mesh.n_nodes), mesh.quads[block].ravel())] == 0)   # only on the solid


@pytest.mark.parametrize("element", ["q2q1", "q1q1"])
@pytest.mark.parametrize("load", ["reaction", "stress-divergence"])
def test_structure_blocks_match_central_differences(load, element):
    rng = np.random.default_rng(31)
    mesh = StructuredQuadMesh(np.array([0, 0.3, 0.7, 1.2]), np.array([0, 0.4, 1.0]))
    flow = Flow(mesh, FluidSettings(viscosity=0.6, density=0.8, alpha_max=40.0, element=element))
    s = Structure(mesh, StructureSettings(youngs_modulus=3.0, load=load), flow)
    u = 0.1 * rng.normal(size=s.size)
    w = rng.normal(size=flow.size)
    X = mesh.points
    x = 0.03 * np.column_stack([np.sin(3 * X[:, 0] + X[:, 1]), np.cos(2 * X[:, 1] - X[:, 0])])
    rho = rng.uniform(0.1, 0.9, mesh.n_elements)
    S = lambda u_=u, w_=w, x_=x, r_=rho: s.residual(u_, w_, x_, r_)
    h = 1e-6
    from tofsi.fem.dirichlet import DirichletOperator
    K = DirichletOperator(s.dofs, s.dofs, s.size, np.zeros(0, int)).matrix(s.element_matrices(rho))
    for _ in range(3):
        du = rng.normal(size=s.size)
        fd = (S(u + h * du) - S(u - h * du)) / (2 * h)
        assert np.linalg.norm(K @ du - fd) <= 1e-8 * np.linalg.norm(fd)
        dw = rng.normal(size=flow.size)
        fd = (S(w_=w + h * dw) - S(w_=w - h * dw)) / (2 * h)
        assert np.linalg.norm(s.fluid_partial(w, x, rho) @ dw - fd) <= 1e-6 * np.linalg.norm(fd)
        lam = rng.normal(size=s.size)                   # the adjoint's product, element by element
        assert s.fluid_partial_transpose(lam, w, x, rho) @ dw == pytest.approx(lam @ fd, rel=1e-6)
        dx = rng.normal(size=(mesh.n_nodes, 2))
        fd = (S(x_=x + h * dx) - S(x_=x - h * dx)) / (2 * h)
        assert np.linalg.norm(s.shape_partial(w, x, rho) @ dx.ravel() - fd) <= 1e-6 * np.linalg.norm(fd)
        dr = rng.normal(size=mesh.n_elements)
        fd = (S(r_=rho + h * dr) - S(r_=rho - h * dr)) / (2 * h)
        assert np.linalg.norm(s.density_partial(u, w, x, rho) @ dr - fd) <= 1e-6 * np.linalg.norm(fd)


def test_clamped_solid_under_its_fluid_load_has_zero_displacement_on_the_clamp():
    mesh = StructuredQuadMesh(np.linspace(0, 2, 21), np.linspace(0, 1, 11))
    rho = ((np.abs(mesh.centroids[:, 0] - 1.0) < 0.1) & (mesh.centroids[:, 1] < 0.5)).astype(float)
    flow = Flow(mesh, FluidSettings(alpha_max=1e5))
    w, _ = flow.solve(rho=rho)
    s = Structure(mesh, StructureSettings(), flow)
    u = s.solve(w, None, rho)
    assert np.all(u[s.bc.fixed] == 0)
    drag, _ = s.force.resultant(w, None, rho)
    assert drag > 0 and s.figures(u, w, None, rho)["compliance"] > 0       # pushed downstream
    assert np.abs(s.bc.homogenize(s.residual(u, w, None, rho))).max() < 1e-9 * np.abs(s.load(w, None, rho)).max()
