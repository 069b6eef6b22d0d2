"""The neo-Hookean element kernel (tofsi.fem.neo_hookean) against independent truths.

* a loop oracle written from the second Piola-Kirchhoff form (S, and the material
  tangent D in 3D with F33 = 1), sharing no code with the kernel;
* hand values: a rigid rotation of 30 degrees is stress free; homogeneous plane-strain
  stretches against the closed form of P; small loads reproduce linear elasticity
  to second order in the load;
* Taylor tests (rate 2) of the tangent and of the density derivative, and the energy
  interpolation's forces as the complex-step gradient of its energy;
* ``g = 0`` is the linear element bit for bit.
"""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from reference_kernels import (GAUSS2, add_gauss_point, distorted_quads, q1_at, random_displacements,
                               taylor_rates)
from tofsi.fem.assembly import element_dofs
from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.fem.neo_hookean import NeoHookeanKernel, NonlinearWeight
from tofsi.physics.interpolation import SIMP
from tofsi.mesh.structured import StructuredQuadMesh

NU = 0.3


# ---- oracle: one element, one Gauss point, one index at a time -------------------------------
def neo_hookean_S_D(F2, lam, mu):
    """Second Piola-Kirchhoff stress and material tangent (2D parts) with F33 = 1."""
    F = np.eye(3, dtype=F2.dtype)
    F[:2, :2] = F2
    C = F.T @ F
    Ci = np.linalg.inv(C)
    log_J = np.log(np.linalg.det(F))
    S = mu * (np.eye(3) - Ci) + lam * log_J * Ci
    D = np.zeros((3, 3, 3, 3), dtype=F2.dtype)
    for i in range(3):
        for j in range(3):
            for k in range(3):
                for l in range(3):
                    D[i, j, k, l] = (lam * Ci[i, j] * Ci[k, l]
                                     + (mu - lam * log_J) * (Ci[i, k] * Ci[j, l] + Ci[i, l] * Ci[j, k]))
    return S[:2, :2], D[:2, :2, :2, :2]


def oracle_quad(X, U, lam, mu):
    """Internal forces (8,), tangent (8, 8) and energy of one quad, index by index."""
    R = np.zeros(8, dtype=U.dtype)
    K = np.zeros((8, 8), dtype=U.dtype)
    W = 0.0
    for xi, eta in GAUSS2:
        _, g, det = q1_at(xi, eta, X)
        F = np.eye(2, dtype=U.dtype) + sum(np.outer(U[a], g[a]) for a in range(4))
        J = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
        W += det * (0.5 * mu * (np.sum(F * F) + 1 - 3) - mu * np.log(J) + 0.5 * lam * np.log(J) ** 2)
        S, D = neo_hookean_S_D(F, lam, mu)
        add_gauss_point(R, K, det, g, F, S, D)
    return R, K, W


def block_mesh(nx=4, ny=3, length=2.0, height=1.0):
    return StructuredQuadMesh(np.linspace(0, length, nx + 1), np.linspace(0, height, ny + 1))


# ---- the kernel against the oracle -------------------------------------------------------------
def test_kernel_matches_the_loop_oracle():
    Xe = distorted_quads(5)
    ue = random_displacements(Xe, 0.2)
    kernel = NeoHookeanKernel(Xe, NU)
    lam, mu = lame(1.0, NU)
    Re, Ke, det_min, W_kernel = kernel.nonlinear(ue)
    assert np.all(det_min > 0.3)                       # large, not inverted
    W = kernel.nonlinear_energy(ue)
    np.testing.assert_allclose(W_kernel, W, rtol=1e-14)
    for e in range(Xe.shape[0]):
        R_o, K_o, W_o = oracle_quad(Xe[e], ue[e].reshape(4, 2), lam, mu)
        np.testing.assert_allclose(Re[e], R_o, rtol=1e-12, atol=1e-13 * np.abs(R_o).max())
        np.testing.assert_allclose(Ke[e], K_o, rtol=1e-12, atol=1e-13 * np.abs(K_o).max())
        assert W[e] == pytest.approx(W_o, rel=1e-12)
    assert np.abs(Re).max() > 0.05                     # not a trivial state


def test_interpolated_forces_are_the_gradient_of_the_interpolated_energy():
    """R_e = dW_e/du_e by complex steps of the energy, for gray elements (0 < g < 1)."""
    Xe = distorted_quads(6, seed=3)
    ue = random_displacements(Xe, 0.15, seed=4)
    kernel = NeoHookeanKernel(Xe, NU)
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
    Rot = np.array([[c, -s], [s, c]])
    u = mesh.points @ Rot.T - mesh.points                        # (n, 2)
    Xe = mesh.points[mesh.quads]
    kernel = NeoHookeanKernel(Xe, NU)
    ue = u[mesh.quads].reshape(-1, 8)
    ones = np.ones(mesh.n_elements)
    Re, _, det_min, W_rot = kernel.evaluate(ue, 7.0 * ones, ones, tangent=False)
    np.testing.assert_allclose(det_min, 1.0, rtol=1e-14)
    force_scale = 7.0 * np.abs(kernel.linear_forces(ue)).max()  # the linear element's spurious force
    assert force_scale > 0.1                                     # small strain is not objective
    assert np.abs(Re).max() < 1e-14 * force_scale
    assert np.abs(W_rot).max() < 1e-14


@pytest.mark.parametrize("stretch", [0.6, 1.3, 2.5])
def test_a_homogeneous_plane_strain_stretch_gives_the_closed_form_traction(stretch):
    """F = diag(l, 1) (and F33 = 1): P11 = mu (l - 1/l) + lam ln(l) / l, P22 = lam ln l. The
    nodal forces on the right edge sum to P11 H, those on the top edge to P22 L."""
    mesh = block_mesh(5, 3, length=2.0, height=1.5)
    u = np.column_stack([(stretch - 1.0) * mesh.points[:, 0], np.zeros(mesh.n_nodes)])
    kernel = NeoHookeanKernel(mesh.points[mesh.quads], NU)
    E0 = 3.0e5
    ones = np.ones(mesh.n_elements)
    Re = kernel.evaluate(u[mesh.quads].reshape(-1, 8), E0 * ones, ones, tangent=False).forces
    f = np.zeros((mesh.n_nodes, 2))
    np.add.at(f, mesh.quads, Re.reshape(-1, 4, 2))
    lam, mu = lame(E0, NU)
    P11 = mu * (stretch - 1 / stretch) + lam * math.log(stretch) / stretch
    P22 = lam * math.log(stretch)
    right, top = mesh.side_nodes("right"), mesh.side_nodes("top")
    assert f[right, 0].sum() == pytest.approx(P11 * 1.5, rel=1e-12)
    assert f[top, 1].sum() == pytest.approx(P22 * 2.0, rel=1e-12)
    interior = np.setdiff1d(np.arange(mesh.n_nodes), mesh.boundary_nodes)
    assert np.abs(f[interior]).max() < 1e-9 * abs(P11)          # equilibrium inside


# ---- a small Newton solver on a block (dense; test only) ----------------------------------------
class Block:
    def __init__(self, mesh, fixed, modulus=1.0, g=1.0):
        self.mesh, self.fixed = mesh, fixed
        self.kernel = NeoHookeanKernel(mesh.points[mesh.quads], NU)
        self.dofs = element_dofs(mesh.quads, 2)
        self.n = 2 * mesh.n_nodes
        self.free = np.setdiff1d(np.arange(self.n), fixed)
        self.modulus = np.full(mesh.n_elements, modulus)
        self.g = np.full(mesh.n_elements, g)

    def forces(self, u):
        Re, Ke, _, _ = self.kernel.evaluate(u[self.dofs], self.modulus, self.g)
        r = np.zeros(self.n)
        K = np.zeros((self.n, self.n))
        np.add.at(r, self.dofs, Re)
        np.add.at(K, (self.dofs[:, :, None], self.dofs[:, None, :]), Ke)
        return r, K

    def solve(self, load, u_fixed=None, guess=None):
        u = np.zeros(self.n) if guess is None else guess.copy()
        if u_fixed is not None:
            u[self.fixed] = u_fixed
        for _ in range(30):
            r, K = self.forces(u)
            res = (r - load)[self.free]
            if np.linalg.norm(res) < 1e-11 * max(np.linalg.norm(load), np.linalg.norm(r)):
                return u, r
            u[self.free] -= np.linalg.solve(K[np.ix_(self.free, self.free)], res)
        raise AssertionError("test Newton did not converge")


def test_plane_strain_uniaxial_stress_against_the_closed_form():
    """Stretch l along x with the lateral faces free (plane strain: F33 = 1): the lateral stretch
    l2 solves mu (l2 - 1/l2) + lam ln(l l2) / l2 = 0 (P22 = 0), and the force is P11 H."""
    mesh = block_mesh(4, 2, length=2.0, height=1.0)
    left, right, bottom = mesh.side_nodes("left"), mesh.side_nodes("right"), mesh.side_nodes("bottom")
    fixed = np.unique(np.concatenate([2 * left, 2 * right, 2 * bottom + 1]))       # rollers
    block = Block(mesh, fixed, modulus=2.0e3)
    lam, mu = lame(2.0e3, NU)
    for stretch in (0.8, 1.5, 2.2):
        u_fixed = np.zeros(fixed.size)
        u_fixed[np.isin(fixed, 2 * right)] = (stretch - 1.0) * 2.0
        guess = np.zeros(block.n)
        guess[0::2] = (stretch - 1.0) * mesh.points[:, 0]              # the axial stretch, no contraction
        u, r = block.solve(np.zeros(block.n), u_fixed, guess)
        l2 = brentq(lambda t, stretch=stretch: mu * (t - 1 / t) + lam * math.log(stretch * t) / t, 0.2, 5.0)
        top = mesh.side_nodes("top")
        np.testing.assert_allclose(u[2 * top + 1], (l2 - 1.0) * 1.0, rtol=1e-10)
        P11 = mu * (stretch - 1 / stretch) + lam * math.log(stretch * l2) / stretch
        assert r[2 * right].sum() == pytest.approx(P11 * 1.0, rel=1e-10)      # reference height 1


def test_small_loads_reproduce_the_linear_model_to_second_order():
    """A cantilever (8 x 2, clamped left) under a tip load t f: |u_NL(t) - t u_L| falls by ~4 when
    t halves (O(t^2)), relative to |t u_L| by ~2."""
    mesh = block_mesh(8, 2, length=4.0, height=1.0)
    fixed = np.concatenate([2 * mesh.side_nodes("left"), 2 * mesh.side_nodes("left") + 1])
    block = Block(mesh, fixed)
    load = np.zeros(block.n)
    load[2 * mesh.side_nodes("right") + 1] = -1.0 / 3
    K0 = block.forces(np.zeros(block.n))[1]
    u_lin = np.zeros(block.n)
    u_lin[block.free] = np.linalg.solve(K0[np.ix_(block.free, block.free)], load[block.free])
    ts = 2e-4 / 2.0 ** np.arange(4)
    gap = np.array([np.linalg.norm(block.solve(t * load)[0] - t * u_lin) for t in ts])
    ratios = gap[:-1] / gap[1:]
    assert np.abs(ts[0] * u_lin).max() > 0.01 * 4.0        # a visible deflection (1 % of the length)
    np.testing.assert_allclose(ratios, 4.0, rtol=0.01)
    assert gap[0] / np.linalg.norm(ts[0] * u_lin) < 0.05


def test_the_kernel_is_the_linear_one_as_the_displacement_vanishes():
    Xe = distorted_quads(5, seed=7)
    kernel = NeoHookeanKernel(Xe, NU)
    ue = random_displacements(Xe, 1.0, seed=8)
    K_at_zero = kernel.nonlinear(np.zeros_like(ue)).tangents
    np.testing.assert_allclose(K_at_zero, element_stiffness(Xe, *lame(1.0, NU)), rtol=1e-12, atol=1e-14)
    gap = [np.abs(kernel.nonlinear(t * ue, tangent=False).forces - t * kernel.linear_forces(ue)).max()
           for t in (1e-3, 5e-4)]
    assert gap[0] / gap[1] == pytest.approx(4.0, rel=0.01)


# ---- Taylor tests ---------------------------------------------------------------------------------
@pytest.mark.parametrize("gray", [False, True])
def test_tangent_taylor_rate_two(gray):
    Xe = distorted_quads(6, seed=11)
    kernel = NeoHookeanKernel(Xe, NU)
    rng = np.random.default_rng(12)
    ue = random_displacements(Xe, 0.2, seed=13)
    modulus = rng.uniform(0.5, 2.0, 6)
    g = rng.uniform(0.05, 0.95, 6) if gray else np.ones(6)
    d = rng.standard_normal(ue.shape)
    Ke = kernel.evaluate(ue, modulus, g).tangents
    rates, r = taylor_rates(lambda e: kernel.evaluate(ue + e * d, modulus, g, tangent=False).forces,
                            np.einsum("eab,eb->ea", Ke, d))
    assert np.all(rates > 1.9), (rates, r)


@pytest.mark.parametrize("weight", [NonlinearWeight(), NonlinearWeight(0.3, 8.0)])
def test_the_nonlinear_weight_is_a_smoothed_step_with_its_derivative(weight):
    assert weight(0.0) == 0.0 and weight(1.0) == pytest.approx(1.0, abs=1e-15)
    rho = np.linspace(0.0, 1.0, 201)
    g = weight(rho)
    assert np.all(np.diff(g) >= 0) and g.min() >= 0 and g.max() <= 1 + 1e-15
    h = 1e-30                                              # complex step of the value
    np.testing.assert_allclose(weight.derivative(rho), weight(rho + 1j * h).imag / h, rtol=1e-12, atol=1e-250)
    if weight.sharpness == 500.0:                          # Wang et al.: linear below 0.01, nonlinear above 0.02
        assert weight(0.005) < 0.08 and weight(0.02) > 0.99


def test_density_derivative_taylor_rate_two():
    """dR_e/drho_e with E(rho) by SIMP and g(rho) a smoothed step (Wang et al.'s form, made
    wide enough that a step of 1e-2 resolves it): both terms."""
    Xe = distorted_quads(6, seed=21)
    kernel = NeoHookeanKernel(Xe, NU)
    rng = np.random.default_rng(22)
    ue = random_displacements(Xe, 0.2, seed=23)
    simp = SIMP(1.0, 1e-3, 3.0)
    rho = rng.uniform(0.1, 0.9, 6)
    direction = rng.standard_normal(6)

    def forces(r):
        return kernel.evaluate(ue, simp(r), weight(r), tangent=False).forces

    weight = NonlinearWeight(0.3, 8.0)
    g, dg = weight(rho), weight.derivative(rho)
    dR = kernel.density_vectors(ue, simp(rho), simp.derivative(rho), g, dg)
    rates, r = taylor_rates(lambda e: forces(rho + e * direction), dR * direction[:, None])
    assert np.all(rates > 1.9), (rates, r)
    # each term alone is visible (a missing term would give rate 1)
    assert np.abs(kernel.density_vectors(ue, simp(rho), 0 * rho, g, dg)).max() > 1e-3 * np.abs(dR).max()


def test_g_zero_is_the_linear_element_exactly():
    Xe = distorted_quads(5, seed=31)
    kernel = NeoHookeanKernel(Xe, NU)
    ue = random_displacements(Xe, 3.0, seed=32)           # large: the nonlinear element would invert
    modulus = np.random.default_rng(33).uniform(0.1, 5.0, 5)
    zero = np.zeros(5)
    Re, Ke, det_min, W_zero = kernel.evaluate(ue, modulus, zero)
    np.testing.assert_array_equal(det_min, 1.0)
    np.testing.assert_array_equal(Re, modulus[:, None] * np.einsum("eab,eb->ea", kernel.K0, ue))
    np.testing.assert_array_equal(Ke, modulus[:, None, None] * kernel.K0)
    np.testing.assert_allclose(W_zero, 0.5 * np.einsum("ea,ea->e", ue, Re), rtol=1e-14)
    assert kernel.nonlinear(ue).forces is None                # the same displacement inverts g = 1


def test_an_inverted_element_is_reported_not_evaluated():
    Xe = distorted_quads(3, seed=41)
    kernel = NeoHookeanKernel(Xe, NU)
    ue = np.zeros((3, 8))
    ue[1, [4, 5]] = -1.5 * (Xe[1, 2] - Xe[1, 0])           # corner 2 pushed through corner 0
    Re, Ke, det_min, W = kernel.evaluate(ue, np.ones(3), np.ones(3))
    assert Re is None and Ke is None and W is None
    assert det_min[1] < 0 and det_min[0] == pytest.approx(1.0) and det_min[2] == pytest.approx(1.0)
