"""The Saint Venant-Kirchhoff element kernel (tofsi.fem.saint_venant_kirchhoff) against
independent truths.

* a loop oracle written from the second Piola-Kirchhoff form (``S = lam tr E I + 2 mu E``
  and the constant material tangent ``D``), sharing no code with the kernel;
* hand values: a rigid rotation of 30 degrees is stress free; homogeneous plane-strain
  stretches against the closed form of ``P = F S``; uniaxial stress (lateral faces free)
  against the closed-form lateral stretch and axial force; small loads reproduce linear
  elasticity to second order in the load;
* Taylor tests (rate 2) of the tangent and of the density derivative, the energy
  interpolation's forces as the complex-step gradient of its energy;
* ``g = 0`` is the linear element bit for bit; an inverted element is reported.
"""

import math

import numpy as np
import pytest

from reference_kernels import (GAUSS2, add_gauss_point, distorted_quads, q1_at, random_displacements,
                               taylor_rates)
from tofsi.fem.assembly import element_dofs
from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.fem.hyperelastic import NonlinearWeight
from tofsi.fem.saint_venant_kirchhoff import SaintVenantKirchhoffKernel
from tofsi.physics.interpolation import SIMP
from tofsi.mesh.structured import StructuredQuadMesh

NU = 0.4             # Turek & Hron's solid


# ---- oracle: one element, one Gauss point, one index at a time -------------------------------
def svk_S_D(F, lam, mu):
    """Second Piola-Kirchhoff stress and the (constant) material tangent, plane strain (2D parts)."""
    E = 0.5 * (F.T @ F - np.eye(2))
    S = lam * np.trace(E) * np.eye(2) + 2 * mu * E
    D = np.zeros((2, 2, 2, 2))
    for i in range(2):
        for j in range(2):
            for k in range(2):
                for m in range(2):
                    D[i, j, k, m] = lam * (i == j) * (k == m) + mu * ((i == k) * (j == m) + (i == m) * (j == k))
    return E, S, D


def oracle_quad(X, U, lam, mu):
    """Internal forces (8,), tangent (8, 8) and energy of one quad, index by index."""
    R = np.zeros(8, dtype=U.dtype)
    K = np.zeros((8, 8), dtype=U.dtype)
    W = 0.0
    for xi, eta in GAUSS2:
        _, g, det = q1_at(xi, eta, X)
        F = np.eye(2, dtype=U.dtype) + sum(np.outer(U[a], g[a]) for a in range(4))
        E, S, D = svk_S_D(F, lam, mu)
        W += det * (0.5 * lam * np.trace(E) ** 2 + mu * np.sum(E * E))
        add_gauss_point(R, K, det, g, F, S, D)
    return R, K, W


def block_mesh(nx=4, ny=3, length=2.0, height=1.0):
    return StructuredQuadMesh(np.linspace(0, length, nx + 1), np.linspace(0, height, ny + 1))


# ---- the kernel against the oracle -------------------------------------------------------------
def test_kernel_matches_the_loop_oracle():
    Xe = distorted_quads(5)
    ue = random_displacements(Xe, 0.2)
    kernel = SaintVenantKirchhoffKernel(Xe, NU)
    lam, mu = lame(1.0, NU)
    Re, Ke, det_min, W_kernel = kernel.nonlinear(ue)
    assert np.all(det_min > 0.3)                       # large, not inverted
    np.testing.assert_allclose(W_kernel, kernel.nonlinear_energy(ue), rtol=1e-14)
    for e in range(Xe.shape[0]):
        R_o, K_o, W_o = oracle_quad(Xe[e], ue[e].reshape(4, 2), lam, mu)
        np.testing.assert_allclose(Re[e], R_o, rtol=1e-12, atol=1e-13 * np.abs(R_o).max())
        np.testing.assert_allclose(Ke[e], K_o, rtol=1e-12, atol=1e-13 * np.abs(K_o).max())
        assert W_kernel[e] == pytest.approx(W_o, rel=1e-12)
    assert np.abs(Re).max() > 0.05                     # not a trivial state
    np.testing.assert_allclose(Ke, Ke.transpose(0, 2, 1), atol=1e-14 * np.abs(Ke).max())   # hyperelastic


def test_interpolated_forces_are_the_gradient_of_the_interpolated_energy():
    """R_e = dW_e/du_e by complex steps of the energy, for gray elements (0 < g < 1)."""
    Xe = distorted_quads(6, seed=3)
    ue = random_displacements(Xe, 0.15, seed=4)
    kernel = SaintVenantKirchhoffKernel(Xe, NU)
    rng = np.random.default_rng(5)
    modulus, g = rng.uniform(0.5, 3.0, 6), rng.uniform(0.0, 1.0, 6)
    Re, _, _, W = kernel.evaluate(ue, modulus, g, tangent=False)
    np.testing.assert_allclose(W, kernel.energy(ue, modulus, g), rtol=1e-13)
    h = 1e-30
    grad = np.stack([kernel.energy(ue + 1j * h * np.eye(8)[j], modulus, g).imag / h for j in range(8)], axis=1)
    np.testing.assert_allclose(Re, grad, rtol=1e-12, atol=1e-14 * np.abs(Re).max())


# ---- hand checks --------------------------------------------------------------------------------
def test_a_rigid_rotation_of_30_degrees_is_stress_free():
    mesh = block_mesh()
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    u = mesh.points @ np.array([[c, -s], [s, c]]).T - mesh.points            # (n, 2)
    kernel = SaintVenantKirchhoffKernel(mesh.points[mesh.quads], NU)
    ue = u[mesh.quads].reshape(-1, 8)
    ones = np.ones(mesh.n_elements)
    Re, _, det_min, W_rot = kernel.evaluate(ue, 7.0 * ones, ones, tangent=False)
    np.testing.assert_allclose(det_min, 1.0, rtol=1e-14)
    force_scale = 7.0 * np.abs(kernel.linear_forces(ue)).max()  # the linear element's spurious force
    assert force_scale > 0.1                                     # small strain is not objective
    assert np.abs(Re).max() < 1e-14 * force_scale
    assert np.abs(W_rot).max() < 1e-14


@pytest.mark.parametrize("stretch", [0.7, 1.3, 2.0])
def test_a_homogeneous_plane_strain_stretch_gives_the_closed_form_traction(stretch):
    """F = diag(l, 1): E11 = (l^2 - 1)/2, S11 = (lam + 2 mu) E11, S22 = lam E11, so P11 = l S11 and
    P22 = S22. The nodal forces on the right edge sum to P11 H, those on the top edge to P22 L."""
    mesh = block_mesh(5, 3, length=2.0, height=1.5)
    u = np.column_stack([(stretch - 1.0) * mesh.points[:, 0], np.zeros(mesh.n_nodes)])
    kernel = SaintVenantKirchhoffKernel(mesh.points[mesh.quads], NU)
    E0 = 1.4e6
    ones = np.ones(mesh.n_elements)
    Re = kernel.evaluate(u[mesh.quads].reshape(-1, 8), E0 * ones, ones, tangent=False).forces
    f = np.zeros((mesh.n_nodes, 2))
    np.add.at(f, mesh.quads, Re.reshape(-1, 4, 2))
    lam, mu = lame(E0, NU)
    E11 = 0.5 * (stretch ** 2 - 1.0)
    P11, P22 = stretch * (lam + 2 * mu) * E11, lam * E11
    right, top = mesh.side_nodes("right"), mesh.side_nodes("top")
    assert f[right, 0].sum() == pytest.approx(P11 * 1.5, rel=1e-12)
    assert f[top, 1].sum() == pytest.approx(P22 * 2.0, rel=1e-12)
    interior = np.setdiff1d(np.arange(mesh.n_nodes), mesh.boundary_nodes)
    assert np.abs(f[interior]).max() < 1e-9 * abs(P11)          # equilibrium inside


def newton(kernel, dofs, n, fixed, u_fixed, guess, modulus):
    """A dense Newton on a small block (test only): internal forces zero on the free dofs."""
    free = np.setdiff1d(np.arange(n), fixed)
    u = guess.copy()
    u[fixed] = u_fixed
    E = dofs.shape[0]
    for _ in range(30):
        Re, Ke, _, _ = kernel.evaluate(u[dofs], np.full(E, modulus), np.ones(E))
        r, K = np.zeros(n), np.zeros((n, n))
        np.add.at(r, dofs, Re)
        np.add.at(K, (dofs[:, :, None], dofs[:, None, :]), Ke)
        if np.linalg.norm(r[free]) < 1e-11 * np.linalg.norm(r):
            return u, r
        u[free] -= np.linalg.solve(K[np.ix_(free, free)], r[free])
    raise AssertionError("test Newton did not converge")


@pytest.mark.parametrize("stretch", [0.85, 1.2, 1.4])
def test_plane_strain_uniaxial_stress_against_the_closed_form(stretch):
    """Stretch l along x with the lateral faces free (plane strain, E33 = 0): S22 = 0 gives
    E22 = -lam E11 / (lam + 2 mu), the lateral stretch sqrt(1 + 2 E22), and the axial force per
    reference height P11 = l S11 = l E11 4 mu (lam + mu) / (lam + 2 mu). Rollers on the left,
    right and bottom sides; Newton on the block."""
    mesh = block_mesh(4, 2, length=2.0, height=1.0)
    left, right, bottom = mesh.side_nodes("left"), mesh.side_nodes("right"), mesh.side_nodes("bottom")
    fixed = np.unique(np.concatenate([2 * left, 2 * right, 2 * bottom + 1]))
    u_fixed = np.where(np.isin(fixed, 2 * right), (stretch - 1.0) * 2.0, 0.0)
    guess = np.zeros(2 * mesh.n_nodes)
    guess[0::2] = (stretch - 1.0) * mesh.points[:, 0]
    E0 = 1.4e6
    kernel = SaintVenantKirchhoffKernel(mesh.points[mesh.quads], NU)
    u, r = newton(kernel, element_dofs(mesh.quads, 2), 2 * mesh.n_nodes, fixed, u_fixed, guess, E0)
    lam, mu = lame(E0, NU)
    E11 = 0.5 * (stretch ** 2 - 1.0)
    E22 = -lam * E11 / (lam + 2 * mu)
    top = mesh.side_nodes("top")
    np.testing.assert_allclose(u[2 * top + 1], math.sqrt(1.0 + 2.0 * E22) - 1.0, rtol=1e-10)
    P11 = stretch * E11 * 4 * mu * (lam + mu) / (lam + 2 * mu)
    assert r[2 * right].sum() == pytest.approx(P11 * 1.0, rel=1e-10)
    assert abs(E22) > 0.01                                     # a visible contraction


def test_the_kernel_is_the_linear_one_as_the_displacement_vanishes():
    """At u = 0 the tangent is K0; the forces differ from K0 u by O(u^2)."""
    Xe = distorted_quads(5, seed=7)
    kernel = SaintVenantKirchhoffKernel(Xe, NU)
    ue = random_displacements(Xe, 1.0, seed=8)
    np.testing.assert_allclose(kernel.nonlinear(np.zeros_like(ue)).tangents, element_stiffness(Xe, *lame(1.0, NU)),
                               rtol=1e-12, atol=1e-14)
    gap = [np.abs(kernel.nonlinear(t * ue, tangent=False).forces - t * kernel.linear_forces(ue)).max()
           for t in (1e-3, 5e-4)]
    assert gap[0] / gap[1] == pytest.approx(4.0, rel=0.01)


# ---- Taylor tests ---------------------------------------------------------------------------------
@pytest.mark.parametrize("gray", [False, True])
def test_tangent_taylor_rate_two(gray):
    Xe = distorted_quads(6, seed=11)
    kernel = SaintVenantKirchhoffKernel(Xe, NU)
    rng = np.random.default_rng(12)
    ue = random_displacements(Xe, 0.2, seed=13)
    modulus = rng.uniform(0.5, 2.0, 6)
    g = rng.uniform(0.05, 0.95, 6) if gray else np.ones(6)
    d = rng.standard_normal(ue.shape)
    Ke = kernel.evaluate(ue, modulus, g).tangents
    rates, r = taylor_rates(lambda e: kernel.evaluate(ue + e * d, modulus, g, tangent=False).forces,
                            np.einsum("eab,eb->ea", Ke, d))
    assert np.all(rates > 1.9), (rates, r)


def test_density_derivative_taylor_rate_two():
    """dR_e/drho_e with E(rho) by SIMP and g(rho) a smoothed step wide enough that a step of
    1e-2 resolves it: both terms."""
    Xe = distorted_quads(6, seed=21)
    kernel = SaintVenantKirchhoffKernel(Xe, NU)
    rng = np.random.default_rng(22)
    ue = random_displacements(Xe, 0.2, seed=23)
    simp = SIMP(1.0, 1e-3, 3.0)
    weight = NonlinearWeight(0.3, 8.0)
    rho = rng.uniform(0.1, 0.9, 6)
    direction = rng.standard_normal(6)
    g, dg = weight(rho), weight.derivative(rho)
    dR = kernel.density_vectors(ue, simp(rho), simp.derivative(rho), g, dg)
    rates, r = taylor_rates(lambda e: kernel.evaluate(ue, simp(rho + e * direction), weight(rho + e * direction),
                                                      tangent=False).forces, dR * direction[:, None])
    assert np.all(rates > 1.9), (rates, r)
    assert np.abs(kernel.density_vectors(ue, simp(rho), 0 * rho, g, dg)).max() > 1e-3 * np.abs(dR).max()


def test_g_zero_is_the_linear_element_exactly_and_an_inverted_element_is_reported():
    Xe = distorted_quads(5, seed=31)
    kernel = SaintVenantKirchhoffKernel(Xe, NU)
    ue = random_displacements(Xe, 3.0, seed=32)           # large: the nonlinear element would invert
    modulus = np.random.default_rng(33).uniform(0.1, 5.0, 5)
    Re, Ke, det_min, W = kernel.evaluate(ue, modulus, np.zeros(5))
    np.testing.assert_array_equal(det_min, 1.0)
    np.testing.assert_array_equal(Re, modulus[:, None] * np.einsum("eab,eb->ea", kernel.K0, ue))
    np.testing.assert_array_equal(Ke, modulus[:, None, None] * kernel.K0)
    np.testing.assert_allclose(W, 0.5 * np.einsum("ea,ea->e", ue, Re), rtol=1e-14)
    inverted = kernel.evaluate(ue, modulus, np.ones(5))
    assert inverted.forces is None and inverted.det_min.min() < 0
    assert np.isnan(kernel.nonlinear_energy(ue)).any()
