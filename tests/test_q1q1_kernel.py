"""The stabilized Q1/Q1 element kernel against its loop oracle, and its derivatives by Taylor tests.

The oracle (tests/q1q1_oracle.py) is written from topFlow's weak form one index at a time; its
complex-step derivatives are exact references for the kernel's Jacobian (tau's dependence on
the velocity included), its friction partial (tau's dependence on alpha included) and its
shape derivatives. The Taylor tests check the same derivatives against the kernel's own
residual: remainder rate 2 when a derivative is complete, ~1 when a term is missing.
"""

import numpy as np
import pytest

from adjoint.checks import taylor_test
from q1q1_oracle import complex_step, residual as oracle
from tofsi.fem.geometry import map_points
from tofsi.physics.fluid_kernel_q1q1 import (POINTS, alpha_partial, element_residual,
                                             shape_derivatives)

CASES = [pytest.param(d, s, f, id=f"rho{d}-{'sym' if s else 'grad'}{'-force' if f else ''}")
         for d, s, f in [(0.0, False, False), (0.0, True, True), (1.3, False, False), (1.3, True, True)]]


def force(x, y):
    """A smooth body force [N/m^3] (complex-safe)."""
    return np.sin(3 * x) * np.cos(2 * y) + 0.5, x * y - np.cos(x + y)


def batch_force(P):
    fx, fy = force(P[..., 0], P[..., 1])
    return np.stack([fx, fy], -1)


def elements(E=5, seed=0):
    """Distorted quads of size ~0.1, velocities, pressures and frictions from 0 to 3e3."""
    rng = np.random.default_rng(seed)
    square = 0.1 * np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    Xe = square[None] + 0.02 * rng.normal(size=(E, 4, 2)) + rng.normal(size=(E, 1, 2))
    ve = rng.normal(size=(E, 4, 2))
    pe = rng.normal(size=(E, 4))
    alpha = np.array([0.0, 1.0, 30.0, 3e3, 500.0][:E])
    return Xe, ve, pe, alpha


def kernel(Xe, ve, pe, alpha, density, symmetric, with_force, jacobian=True):
    f = batch_force(map_points(Xe, POINTS)) if with_force else None
    return element_residual(Xe, ve, pe, alpha, density, 0.7, symmetric, f, jacobian)


@pytest.mark.parametrize("density, symmetric, with_force", CASES)
def test_residual_matches_the_loop_oracle(density, symmetric, with_force):
    Xe, ve, pe, alpha = elements()
    Re, _ = kernel(Xe, ve, pe, alpha, density, symmetric, with_force, jacobian=False)
    for e in range(len(Xe)):
        ref = oracle(Xe[e], ve[e], pe[e], alpha[e], density, 0.7, symmetric, force if with_force else None)
        np.testing.assert_allclose(Re[e], ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("density, symmetric, with_force", CASES)
def test_jacobian_is_the_oracles_exact_derivative_tau_included(density, symmetric, with_force):
    Xe, ve, pe, alpha = elements()
    _, Ke = kernel(Xe, ve, pe, alpha, density, symmetric, with_force)
    f = force if with_force else None
    for e in range(len(Xe)):
        ref = complex_step(lambda s, e=e: oracle(Xe[e], s[:8].reshape(4, 2), s[8:], alpha[e], density, 0.7,
                                            symmetric, f), np.concatenate([ve[e].ravel(), pe[e]]))
        np.testing.assert_allclose(Ke[e], ref, rtol=0, atol=1e-11 * np.abs(ref).max())


def test_jacobian_passes_the_taylor_test_at_navier_stokes():
    """Remainder rate 2 along a random direction in (v, p) of every element at once, at element
    Reynolds numbers ~20 where tau_adv dominates tau (rate ~1 without d tau / d v)."""
    Xe, ve, pe, alpha = elements()
    ve = 100 * ve
    rng = np.random.default_rng(1)
    s0 = np.concatenate([ve.reshape(len(Xe), 8), pe], axis=1)
    ds = rng.normal(size=s0.shape)
    lam = rng.normal(size=s0.shape)

    def value(s):
        Re, _ = kernel(Xe, s[:, :8].reshape(-1, 4, 2), s[:, 8:], alpha, 1.3, True, True, jacobian=False)
        return float(np.sum(lam * Re))
    _, Ke = kernel(Xe, ve, pe, alpha, 1.3, True, True)
    grad = np.einsum("ea,eab->eb", lam, Ke)
    t = taylor_test(lambda z: value(z.reshape(s0.shape)), s0.ravel(), grad.ravel(), ds.ravel())
    assert t.min_rate > 1.9, t


@pytest.mark.parametrize("density", [0.0, 1.3])
def test_friction_partial_includes_tau(density):
    Xe, ve, pe, alpha = elements()
    alpha = alpha + 10.0                                       # away from alpha = 0 (tau's kink-free anyway)
    dR = alpha_partial(Xe, ve, pe, alpha, density, 0.7, True, batch_force(map_points(Xe, POINTS)))
    for e in range(len(Xe)):
        ref = complex_step(lambda a, e=e: oracle(Xe[e], ve[e], pe[e], a[0], density, 0.7, True, force),
                           np.array([alpha[e]]))[:, 0]
        np.testing.assert_allclose(dR[e], ref, rtol=0, atol=1e-11 * np.abs(ref).max())
    rng = np.random.default_rng(2)
    lam, da = rng.normal(size=dR.shape), rng.normal(size=alpha.shape) * alpha

    def value(a):
        Re, _ = element_residual(Xe, ve, pe, a, density, 0.7, True, batch_force(map_points(Xe, POINTS)), False)
        return float(np.sum(lam * Re))
    t = taylor_test(value, alpha, np.sum(lam * dR, axis=1), da)
    assert t.min_rate > 1.9, t


@pytest.mark.parametrize("density", [0.0, 1.3])
def test_shape_derivatives_match_the_oracle_and_pass_the_taylor_test(density):
    Xe, ve, pe, alpha = elements()
    at = lambda X: batch_force(map_points(X, POINTS))
    Re, dR = shape_derivatives(Xe, ve, pe, alpha, density, 0.7, True, at)
    for e in range(len(Xe)):
        ref = complex_step(lambda X, e=e: oracle(X.reshape(4, 2), ve[e], pe[e], alpha[e], density, 0.7, True, force),
                           Xe[e].ravel())
        np.testing.assert_allclose(dR[e], ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    rng = np.random.default_rng(3)
    lam, dX = rng.normal(size=Re.shape), 0.01 * rng.normal(size=Xe.shape)

    def value(X):
        X = X.reshape(Xe.shape)
        return float(np.sum(lam * element_residual(X, ve, pe, alpha, density, 0.7, True, at(X), False)[0]))
    t = taylor_test(value, Xe.ravel(), np.einsum("ea,eac->ec", lam, dR).ravel(), dX.ravel())
    assert t.min_rate > 1.9, t


def test_frictionless_stokes_jacobian_is_the_symmetric_saddle_form():
    """Stokes, gradient form, alpha = 0: [[A, B^T], [B, -C]] with C = tau_p int grad N . grad N
    positive semi-definite (PSPG's pressure block); friction adds the unsymmetric PSPG term
    -tau_p int alpha grad N_c . N_b to B."""
    Xe, ve, pe, _ = elements()
    _, Ke = element_residual(Xe, ve, pe, np.zeros(len(Xe)), 0.0, 0.7, False, None)
    np.testing.assert_allclose(Ke, np.swapaxes(Ke, 1, 2), rtol=0, atol=1e-13 * np.abs(Ke).max())
    C = -Ke[:, 8:, 8:]
    assert np.all(np.linalg.eigvalsh(C) > -1e-14 * np.abs(C).max())
