"""Yeoh material and mover: stress and tangent by finite differences, kernels, Newton."""

import numpy as np
import pytest

from movers.base import MotionProblem
from movers.yeoh import YeohKernel, YeohMover, YeohParams
from movers import yeoh_kernel
from movers.yeoh_material import BLOCKS, energy, piola_and_elasticity, stress_and_tangent
from reference_kernels import yeoh_quad
from tofsi.core.errors import NumericalError
from tofsi.mesh.structured import StructuredQuadMesh

PARAMS = dict(A10=1.3, A20=7.0, A30=2.5, kappa=3.0)


def voigt(E):
    """Strain in Voigt form with engineering shear."""
    return np.array([E[0, 0], E[1, 1], 2 * E[0, 1]])


@pytest.fixture
def F():
    rng = np.random.default_rng(5)
    return np.eye(2) + 0.3 * rng.normal(size=(2, 2))


def test_first_piola_stress_is_the_energy_gradient(F):
    S, _ = stress_and_tangent(F, **PARAMS)
    P = F @ S
    h = 1e-6
    fd = np.zeros((2, 2))
    for i in range(2):
        for J in range(2):
            dF = np.zeros((2, 2))
            dF[i, J] = h
            fd[i, J] = (energy(F + dF, **PARAMS) - energy(F - dF, **PARAMS)) / (2 * h)
    np.testing.assert_allclose(P, fd, rtol=1e-6)


def test_tangent_is_the_stress_derivative(F):
    S, D = stress_and_tangent(F, **PARAMS)
    rng = np.random.default_rng(6)
    h = 1e-6
    for _ in range(4):
        dF = rng.normal(size=(2, 2))
        dS = (stress_and_tangent(F + h * dF, **PARAMS)[0] - stress_and_tangent(F - h * dF, **PARAMS)[0]) / (2 * h)
        dE = 0.5 * (dF.T @ F + F.T @ dF)
        dS_voigt = np.array([dS[0, 0], dS[1, 1], dS[0, 1]])       # stress: no factor 2
        assert np.linalg.norm(dS_voigt - D @ voigt(dE)) <= 1e-6 * np.linalg.norm(D @ voigt(dE))


def test_out_of_plane_stretch_counts_in_I1():
    """Uniaxial in-plane stretch: I1 = l^2 + 1 + 1, so W = A10 (J1 - 3) with J1 from 3 terms."""
    lam = 1.2
    F = np.diag([lam, 1.0])
    J1 = (lam**2 + 2) * lam ** (-2 / 3)
    assert energy(F, 1.0, 0.0, 0.0, 0.0) == pytest.approx(J1 - 3, rel=1e-14)


def test_small_strain_limit_gives_shear_2A10_and_bulk_2kappa():
    """At F = I the tangent is isotropic with mu = 2 A10 and (plane-strain) lambda = K - 2 mu / 3."""
    A10, kappa = 0.7, 5.0
    _, D = stress_and_tangent(np.eye(2), A10, 100.0, 3.0, kappa)
    mu, K = 2 * A10, 2 * kappa
    lam = K - 2 * mu / 3
    expected = np.array([[lam + 2 * mu, lam, 0], [lam, lam + 2 * mu, 0], [0, 0, mu]])
    np.testing.assert_allclose(D, expected, rtol=1e-13, atol=1e-13)


def component_first(F):
    """Stack (N, 2, 2) -> component-first (2, 2, N)."""
    return np.ascontiguousarray(np.moveaxis(F, 0, -1))


def test_pulled_back_piola_stress_is_the_energy_gradient():
    """``Pt = w (dW/dF) B^T`` by central differences of the energy, for random F, B, w."""
    rng = np.random.default_rng(15)
    Fs = np.eye(2) + 0.3 * rng.normal(size=(3, 2, 2))
    B, w = rng.normal(size=(2, 2, 3)), rng.uniform(0.5, 2.0, 3)
    Pt, _ = piola_and_elasticity(component_first(Fs), **PARAMS, pull=B, weight=w, tangent=False)
    h = 1e-6
    dW = np.zeros((3, 2, 2))
    for i in range(2):
        for J in range(2):
            dF = np.zeros((2, 2))
            dF[i, J] = h
            dW[:, i, J] = (energy(Fs + dF, **PARAMS) - energy(Fs - dF, **PARAMS)) / (2 * h)
    expected = w * np.einsum("niJ,mJn->imn", dW, B)
    np.testing.assert_allclose(Pt, expected, rtol=1e-6)


def test_first_elasticity_tensor_is_the_piola_stress_derivative():
    """``At_ikmn = w dP_iJ/dF_kL B_mJ B_nL`` by central differences of P."""
    rng = np.random.default_rng(16)
    F = component_first(np.eye(2) + 0.3 * rng.normal(size=(3, 2, 2)))
    B, w = rng.normal(size=(2, 2, 3)), rng.uniform(0.5, 2.0, 3)
    _, At = piola_and_elasticity(F, **PARAMS, pull=B, weight=w)
    h = 1e-6
    dP = np.zeros((2, 2, 2, 2, 3))                                   # [i, J, k, L, n]
    for k in range(2):
        for L in range(2):
            dF = np.zeros((2, 2, 1))
            dF[k, L] = h
            plus, _ = piola_and_elasticity(F + dF, **PARAMS, tangent=False)
            minus, _ = piola_and_elasticity(F - dF, **PARAMS, tangent=False)
            dP[:, :, k, L] = (plus - minus) / (2 * h)
    for b, (i, k) in enumerate(BLOCKS):
        expected = w * np.einsum("JLn,mJn,qLn->mqn", dP[i, :, k], B, B)
        np.testing.assert_allclose(At[b], expected, rtol=1e-6, atol=1e-8 * np.abs(expected).max())


def test_first_elasticity_tensor_is_the_push_forward_of_the_material_tangent():
    """A different formulation: ``A_iJkL = F_iI D_IJKL F_kK + delta_ik S_JL`` from (S, D) in Voigt form."""
    rng = np.random.default_rng(17)
    Fs = np.eye(2) + 0.3 * rng.normal(size=(4, 2, 2))
    P, At = piola_and_elasticity(component_first(Fs), **PARAMS)
    S, D = stress_and_tangent(Fs, **PARAMS)
    v = np.array([[0, 2], [2, 1]])                                   # Voigt index of (I, J)
    D4 = D[:, v[:, :, None, None], v[None, None, :, :]]               # (n, I, J, K, L)
    A = np.einsum("niI,nIJKL,nkK->niJkL", Fs, D4, Fs) + np.einsum("ik,nJL->niJkL", np.eye(2), S)
    np.testing.assert_allclose(np.moveaxis(P, -1, 0), Fs @ S, rtol=1e-12, atol=1e-12)
    for b, (i, k) in enumerate(BLOCKS):
        np.testing.assert_allclose(np.moveaxis(At[b], -1, 0), A[:, i, :, k], rtol=1e-12, atol=1e-11)


@pytest.mark.parametrize("block", [2, 5, 1000])
def test_kernel_on_element_blocks_matches_the_slow_oracle(monkeypatch, block):
    """Whole blocks, a partial last block and one block for all: the same element values."""
    monkeypatch.setattr(yeoh_kernel, "BLOCK", block)
    rng = np.random.default_rng(18)
    mesh = StructuredQuadMesh(np.array([0, 0.3, 0.5, 1.0]), np.array([0, 0.2, 0.5, 0.7, 1.0]))
    problem = MotionProblem.from_mesh(mesh, np.arange(mesh.n_elements), np.array([0]),
                                      stiffening=rng.uniform(1, 3, mesh.n_elements))
    p = YeohParams(**PARAMS)
    x = 0.05 * rng.normal(size=2 * mesh.n_nodes)
    Re, Ke, _ = YeohKernel(problem, p).evaluate(x)
    for e, q in enumerate(problem.quads):
        R, K = yeoh_quad(mesh.points[q], x.reshape(-1, 2)[q], p.A10, p.A20 * problem.stiffening[e], p.A30, p.kappa)
        np.testing.assert_allclose(Re[e], R, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(Ke[e], K, rtol=1e-12, atol=1e-12)


def test_vectorized_kernel_matches_the_slow_oracle():
    rng = np.random.default_rng(7)
    mesh = StructuredQuadMesh(np.array([0, 0.4, 1.0]), np.array([0, 0.3, 0.8]))
    problem = MotionProblem.from_mesh(mesh, np.arange(mesh.n_elements), np.array([0]),
                                      stiffening=np.array([1.0, 2.0, 1.5, 3.0]))
    p = YeohParams(**PARAMS)
    x = 0.08 * rng.normal(size=2 * mesh.n_nodes)
    Re, Ke, _ = YeohKernel(problem, p).evaluate(x)
    for e, q in enumerate(problem.quads):
        R, K = yeoh_quad(mesh.points[q], x.reshape(-1, 2)[q], p.A10, p.A20 * problem.stiffening[e], p.A30, p.kappa)
        np.testing.assert_allclose(Re[e], R, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(Ke[e], K, rtol=1e-12, atol=1e-12)


def test_element_tangent_is_the_residual_derivative():
    rng = np.random.default_rng(8)
    mesh = StructuredQuadMesh(np.array([0, 0.5, 1.0]), np.array([0, 0.6]))
    problem = MotionProblem.from_mesh(mesh, np.arange(2), np.array([0]))
    kernel = YeohKernel(problem, YeohParams(**PARAMS))
    x = 0.1 * rng.normal(size=2 * mesh.n_nodes)
    _, Ke, _ = kernel.evaluate(x)
    h = 1e-6
    for d in range(8):
        e = np.zeros_like(x)
        e[2 * problem.quads[0][d // 2] + d % 2] = h
        fd = (kernel.evaluate(x + e, tangent=False)[0][0] - kernel.evaluate(x - e, tangent=False)[0][0]) / (2 * h)
        np.testing.assert_allclose(Ke[0][:, d], fd, rtol=1e-6, atol=1e-8)


def _plate(n=10):
    mesh = StructuredQuadMesh(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    boundary = np.unique(np.concatenate([mesh.side_nodes(s) for s in ("left", "right", "bottom", "top")]))
    return mesh, MotionProblem.from_mesh(mesh, np.arange(mesh.n_elements), boundary)


def test_newton_converges_quadratically():
    mesh, problem = _plate()
    u = np.zeros((mesh.n_nodes, 2))
    top = mesh.side_nodes("top")
    u[top, 0] = 0.25 * np.sin(np.pi * mesh.points[top, 0])
    result = YeohMover(YeohParams(increments=1, newton_tol=1e-13)).move(problem, u)
    history = [h for h in result.report.residual_history if len(h) >= 4][0]
    r = np.array(history) / history[0]
    # observed order p_k = log(r_{k+1} / r_k) / log(r_k / r_{k-1}), above the round-off floor
    orders = [np.log(r[k + 1] / r[k]) / np.log(r[k] / r[k - 1])
              for k in range(1, len(r) - 1) if r[k + 1] > 1e-13 and r[k] < 1e-2]
    assert orders and max(orders) > 1.8, history


def test_oversized_first_increment_is_cut_back_and_converges():
    mesh, problem = _plate(8)
    u = np.zeros((mesh.n_nodes, 2))
    top = mesh.side_nodes("top")
    u[top, 1] = -0.8 * np.sin(np.pi * mesh.points[top, 0])      # crush the lid to 20 % height
    result = YeohMover(YeohParams(increments=1)).move(problem, u)
    assert result.report.cutbacks >= 1 and result.report.converged
    assert result.report.quality[-1]["n_inverted"] == 0
    np.testing.assert_allclose(result.displacement[top], u[top], atol=1e-14)


def test_impossible_motion_fails_with_a_diagnostic_not_nan():
    mesh, problem = _plate(6)
    u = np.zeros((mesh.n_nodes, 2))
    top = mesh.side_nodes("top")
    u[top[1:-1], 1] = -1.5                                          # lid through the floor
    with pytest.raises(NumericalError) as err:
        YeohMover(YeohParams(increments=2, max_cutbacks=8)).move(problem, u)
    diag = err.value.diagnostic
    assert diag["report"]["cutbacks"] >= 1 and not diag["report"]["converged"]
    assert np.all(np.isfinite(err.value.state))
    assert "worst_element" in diag["quality"]


def test_a_looser_tolerance_stops_newton_early_at_that_residual():
    """``move(..., tol=...)`` (a coupled sweep's start) stops where ``|D_free|`` falls below
    ``tol`` of the force scale (here the forces of the boundary's motion alone, the first
    residual): fewer Newton steps than ``newton_tol``, its residual (the residual form's, an
    independent evaluation) between the two tolerances, the displacement that of the full
    solve to about that fraction."""
    mesh, problem = _plate()
    u = np.zeros((mesh.n_nodes, 2))
    top = mesh.side_nodes("top")
    u[top, 0] = 0.25 * np.sin(np.pi * mesh.points[top, 0])
    mover = YeohMover(YeohParams(increments=1, newton_tol=1e-12))
    full, loose = mover.move(problem, u), mover.move(problem, u, tol=1e-3)
    assert loose.report.newton_iterations < full.report.newton_iterations
    free = ~problem.bc.is_fixed
    boundary_only = np.where(free, 0.0, u.ravel())                 # the boundary moved, the rest at rest
    forces = np.linalg.norm(mover.residual(problem, boundary_only, u.ravel(), jacobian=False)[0][free])
    d_loose = np.linalg.norm(mover.residual(problem, loose.displacement.ravel(), u.ravel(), jacobian=False)[0][free])
    d_full = np.linalg.norm(mover.residual(problem, full.displacement.ravel(), u.ravel(), jacobian=False)[0][free])
    assert d_full < 1e-10 * forces and 1e-10 * forces < d_loose < 1e-3 * forces
    change = np.linalg.norm(loose.displacement - full.displacement) / np.linalg.norm(full.displacement)
    assert change < 1e-2
