"""Stabilized equal-order Q1/Q1 element kernel: steady Navier-Stokes with Brinkman friction.

The element of Alexandersen's topFlow (SMO 66:12, 2023; ``analyticalElement.m``) and of
TOFLUX: velocity and pressure both bilinear on the 4 corners. Element unknowns
node-interleaved velocity ``[v0x, v0y, ..., v3x, v3y]`` (8), then pressure (4).
With ``N`` the Q1 shape functions, the strong momentum residual without its viscous
part (zero or nearly so for bilinear fields)

    r = alpha v + rho_f (v . grad) v + grad p - f                       [N/m^3]

and ``T = mu grad v - p I`` (gradient form) or ``mu (grad v + grad v^T) - p I``
(symmetric form, topFlow's), the residual is

    R_v[a, i] = int N_a (alpha v_i + rho_f (v . grad) v_i - f_i) + T_ij dN_a/dx_j
                + tau_s (v . grad N_a) r_i                               (Galerkin + SUPG)
    R_p[c]    = -int N_c div v  -  tau_p int grad N_c . r                (Galerkin + PSPG)

(the continuity row's sign as in the Taylor-Hood kernel, so the Stokes Jacobian is the
symmetric ``[[A, B^T], [B, -C]]``). The stabilization parameter is topFlow's, per element:

    tau   = (1/tau_adv^2 + 1/tau_visc^2 + 1/tau_brink^2)^(-1/2)              [s]
    tau_adv = h / (2 |v_0|),  tau_visc = rho_f h^2 / (12 mu),  tau_brink = rho_f / alpha

with ``v_0`` the velocity at the element centre and ``h`` the element diagonal
(``h^2 = (|X_2 - X_0|^2 + |X_3 - X_1|^2) / 2``, topFlow's ``sqrt(dx^2 + dy^2)`` on a
rectangle). SUPG uses ``tau_s = tau``, PSPG ``tau_p = tau / rho_f``:

    tau_p = (4 rho_f^2 |v_0|^2 / h^2 + (12 mu / h^2)^2 + alpha^2)^(-1/2)    [m^3 s/kg]

which stays finite in Stokes flow (``rho_f = 0``: no SUPG, the classic PSPG
``h^2 / (12 mu)`` damped by the friction). ``|v_0|^2`` enters squared, so ``tau`` is smooth
in ``v``; the Jacobian is the exact derivative including ``d tau / d v`` (as topFlow's
symbolic one), and :func:`alpha_partial` includes ``d tau / d alpha``. 2x2 Gauss points
(TOFLUX's rule) integrate every term exactly on rectangles, as topFlow's symbolic
integration does, except the SUPG convection ``tau_s (v . grad N_a) rho_f (v . grad) v``
(degree 4 per direction), of size ``rho_f^2`` (1e-6 of the residual at topFlow's
``rho_f = 1e-3``); 3x3 points would double the kernel's cost.

All inputs may be complex (``|v_0|^2`` is ``v_0 . v_0`` without conjugation), so shape
derivatives with respect to the corners come from the same code by the complex step
(:func:`shape_derivatives`).
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.complex_step import corner_derivatives
from tofsi.fem.geometry import physical_gradients
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions
from tofsi.core.kept import Kept, input_key

POINTS, WEIGHTS = gauss_square(2)
N1, _ = shape_functions(1, POINTS)            # (G, 4)
_BASIS = Kept()                               # the last configuration's basis, keyed by its corners


def basis(Xe):
    """Physical gradients ``(E, G, 4, 2)`` and weights ``w det J`` ``(E, G)`` of corners ``Xe``;
    the last configuration's are kept (keyed by the corners' values: a one-way flow's Newton
    steps, line search and adjoint all see the same mesh)."""
    def build():
        grad, det = physical_gradients(Xe, 1, POINTS)
        return grad, det * WEIGHTS
    return _BASIS.get(input_key(np.asarray(Xe)), build)


def diagonal_squared(Xe):
    """``h^2 = (|X_2 - X_0|^2 + |X_3 - X_1|^2) / 2`` ``(E,)`` [m^2] (complex-safe)."""
    d1, d2 = Xe[:, 2] - Xe[:, 0], Xe[:, 3] - Xe[:, 1]
    return 0.5 * (d1[:, 0] ** 2 + d1[:, 1] ** 2 + d2[:, 0] ** 2 + d2[:, 1] ** 2)


def stabilization(Xe, ve, alpha, density: float, viscosity: float):
    """``tau_p`` ``(E,)`` [m^3 s/kg], ``dtau_p/dv_e`` ``(E, 2)`` (the same for every corner's
    velocity) and ``dtau_p/dalpha`` ``(E,)``; ``tau_s = density tau_p``."""
    h2 = diagonal_squared(Xe)
    v0 = ve.mean(axis=1)                                          # centre velocity (E, 2)
    speed2 = v0[:, 0] ** 2 + v0[:, 1] ** 2
    s = 4 * density**2 * speed2 / h2 + (12 * viscosity / h2) ** 2 + alpha**2
    tau_p = s ** -0.5
    # d s / d v_(b,k) = 8 density^2 v0_k / (4 h^2) for each corner b
    dtau_dv = (-0.5 * tau_p**3 * 2 * density**2 / h2)[:, None] * v0
    dtau_dalpha = -tau_p**3 * alpha
    return tau_p, dtau_dv, dtau_dalpha


class _Fields:
    """The quantities at the Gauss points shared by the residual and its derivatives."""

    def __init__(self, Xe, ve, pe, alpha, density, viscosity, symmetric, force):
        grad, w = basis(Xe)                                          # (E, G, 4, 2), (E, G)
        self.grad, self.w = grad, w
        self.v = np.matmul(N1, ve)                                   # (E, G, 2)
        self.L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)    # L_ij = dv_i/dx_j (E, G, 2, 2)
        self.p = np.matmul(pe, N1.T)                                 # (E, G)
        self.gp = np.matmul(pe[:, None, None, :], grad)[:, :, 0]     # grad p (E, G, 2)
        self.adv = np.matmul(grad, self.v[..., None])[..., 0]        # v . grad N_a (E, G, 4)
        conv = density * np.matmul(self.L, self.v[..., None])[..., 0]
        source = alpha[:, None, None] * self.v + conv                # (E, G, 2)
        if force is not None:
            source = source - force
        self.source = source                                         # Galerkin body terms
        self.r = source + self.gp                                    # strong residual (E, G, 2)
        self.tau_p, self.dtau_dv, self.dtau_dalpha = stabilization(Xe, ve, alpha, density, viscosity)
        self.tau_s = density * self.tau_p
        mu = viscosity
        T = mu * (self.L + np.swapaxes(self.L, -1, -2) if symmetric else self.L)
        self.T = T - self.p[..., None, None] * np.eye(2)
        # int (v . grad N_a) r_i (E, 4, 2) and int grad N_c . r (E, 4): tau's derivative terms
        self.adv_r = np.matmul(np.swapaxes(self.adv * self.w[..., None], 1, 2), self.r)
        self.grad_r = np.sum(np.matmul(self.grad, self.r[..., None])[..., 0] * self.w[..., None], axis=1)


def element_residual(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False,
                     force=None, jacobian: bool = True):
    """Element residuals ``(E, 12)`` and Jacobians ``(E, 12, 12)`` (or None).

    Xe (E, 4, 2) corners [m]; ve (E, 4, 2) [m/s]; pe (E, 4) [Pa]; alpha (E,) [kg/(m^3 s)];
    force (E, G, 2) body force at the Gauss points [N/m^3] or None.
    """
    E = Xe.shape[0]
    F = _Fields(Xe, ve, pe, alpha, density, viscosity, symmetric, force)
    w = F.w
    Rv = np.matmul(N1.T, F.source * w[..., None])                                  # (E, 4, 2)
    Rv = Rv + (np.matmul(F.grad, np.swapaxes(F.T, -1, -2)) * w[..., None, None]).sum(axis=1)
    Rv = Rv + F.tau_s[:, None, None] * F.adv_r                                      # SUPG
    div = F.L[..., 0, 0] + F.L[..., 1, 1]
    Rp = -np.matmul(div * w, N1) - F.tau_p[:, None] * F.grad_r                       # (E, 4)
    Re = np.concatenate([Rv.reshape(E, 8), Rp], axis=1)
    if not jacobian:
        return Re, None
    return Re, _jacobian(F, alpha, density, viscosity, symmetric)


def _jacobian(F, alpha, density, viscosity, symmetric):
    """The exact derivative of :func:`element_residual` in ``(ve, pe)`` ``(E, 12, 12)``."""
    grad, w, L = F.grad, F.w, F.L
    E, G = w.shape
    mu = viscosity
    gw = grad * w[..., None, None]                                                 # (E, G, 4, 2)
    test = (N1[None] + F.tau_s[:, None, None] * F.adv) * w[..., None]               # N_a + SUPG (E, G, 4)
    trial = alpha[:, None, None] * N1[None] + density * F.adv                       # d r_i/d v_(b,i) (E, G, 4)
    # int grad N_a_j grad N_b_m (E, 4, 2, 4, 2)
    M = np.matmul(gw.reshape(E, G, 8).transpose(0, 2, 1), grad.reshape(E, G, 8)).reshape(E, 4, 2, 4, 2)
    lap = M[:, :, 0, :, 0] + M[:, :, 1, :, 1]                                      # (E, 4, 4)
    diag = mu * lap + np.matmul(test.transpose(0, 2, 1), trial)                    # (E, 4, 4)
    if density:
        # rho test_a L_ik + tau_s dN_a/dx_k r_i (the SUPG test's derivative), against N_b:
        # one product over the points for both [a, i, k] x b
        Z = density * test[..., :, None, None] * L[:, :, None, :, :]              # (E, G, 4, 2, 2)
        Z += F.tau_s[:, None, None, None, None] * grad[:, :, :, None, :] * (F.r * w[..., None])[:, :, None, :, None]
        conv = np.matmul(Z.reshape(E, G, 16).transpose(0, 2, 1), N1).reshape(E, 4, 2, 2, 4)   # [a, i, k, b]
        Kvv = np.ascontiguousarray(conv.transpose(0, 1, 2, 4, 3))                  # [a, i, b, k]
        # tau_s's derivative: int (v . grad N_a) r_i  x  density dtau_p/dv_(b,k)
        Kvv += density * F.adv_r[:, :, :, None, None] * F.dtau_dv[:, None, None, None, :]
    else:
        Kvv = np.zeros((E, 4, 2, 4, 2), dtype=np.result_type(F.r, grad))
    Kvv[:, :, 0, :, 0] += diag
    Kvv[:, :, 1, :, 1] += diag
    if symmetric:                                                                  # mu dN_a/dx_k dN_b/dx_i
        Kvv += mu * np.swapaxes(M, 2, 4)
    Kvp = -np.matmul(gw.reshape(E, G, 8).transpose(0, 2, 1), N1)                   # -int dN_a/dx_i N_b (E, 8, 4)
    supg_p = np.matmul(np.swapaxes(F.adv * w[..., None], 1, 2), grad.reshape(E, G, 8)).reshape(E, 4, 4, 2)
    Kvp = Kvp + F.tau_s[:, None, None] * supg_p.transpose(0, 1, 3, 2).reshape(E, 8, 4)
    # continuity rows: -int N_c dN_b/dx_k - tau_p int dN_c/dx_k trial_b
    #                  - tau_p rho int (grad N_c . L)_k N_b - dtau_p/dv_(b,k) int grad N_c . r
    Kpv = -np.matmul((N1[None] * w[..., None]).transpose(0, 2, 1), grad.reshape(E, G, 8)).reshape(E, 4, 4, 2)
    pspg = np.matmul(gw.reshape(E, G, 8).transpose(0, 2, 1), trial).reshape(E, 4, 2, 4)   # [c, k, b]
    if density:
        GL = np.matmul(grad, L) * w[..., None, None]                               # (grad N_c . L)_k (E, G, 4, 2)
        pspg = pspg + density * np.matmul(GL.reshape(E, G, 8).transpose(0, 2, 1), N1).reshape(E, 4, 2, 4)
        Kpv = Kpv - F.grad_r[:, :, None, None] * F.dtau_dv[:, None, None, :]
    Kpv = Kpv - F.tau_p[:, None, None, None] * pspg.transpose(0, 1, 3, 2)
    Ke = np.empty((E, 12, 12), dtype=Kvv.dtype)
    Ke[:, :8, :8] = Kvv.reshape(E, 8, 8)
    Ke[:, :8, 8:] = Kvp
    Ke[:, 8:, :8] = Kpv.reshape(E, 4, 8)
    Ke[:, 8:, 8:] = -F.tau_p[:, None, None] * lap
    return Ke


def alpha_partial(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False,
                  force=None):
    """``dR_e/dalpha_e`` ``(E, 12)``: the friction in the Galerkin and stabilization terms and
    in ``tau`` (``dtau_p/dalpha = -tau_p^3 alpha``)."""
    E = Xe.shape[0]
    F = _Fields(Xe, ve, pe, alpha, density, viscosity, symmetric, force)
    w = F.w
    test = (N1[None] + F.tau_s[:, None, None] * F.adv) * w[..., None]              # (E, G, 4)
    dv = np.matmul(test.transpose(0, 2, 1), F.v) + (density * F.dtau_dalpha)[:, None, None] * F.adv_r
    gv = np.sum(np.matmul(F.grad, F.v[..., None])[..., 0] * w[..., None], axis=1)    # int grad N_c . v
    dp = -F.tau_p[:, None] * gv - F.dtau_dalpha[:, None] * F.grad_r
    return np.concatenate([dv.reshape(E, 8), dp], axis=1)


def shape_derivatives(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False,
                      force_at=None):
    """``(R_e (E, 12), dR_e/dXe (E, 12, 8))`` by the complex step (column ``2 k + m``: corner
    ``k``, coordinate ``m``). ``force_at``: body force ``f(Xe) -> (E, G, 2)`` evaluated on the
    configuration (complex-safe), or None."""
    def residual(Xc):
        force = None if force_at is None else force_at(Xc)
        return element_residual(Xc, ve, pe, alpha, density, viscosity, symmetric, force, jacobian=False)[0]
    return residual(Xe), corner_derivatives(residual, Xe)
