"""Plane-strain compressible neo-Hookean elements on Q1 quads (total Lagrangian, batched).

Per unit Young's modulus (``lam, mu`` = :func:`~tofsi.fem.elasticity.lame` of
``(1, nu)``), with ``F = I + grad_X u`` the 2x2 deformation gradient
(``F33 = 1``), ``C = F^T F`` and ``J = det F``::

    W_NL(F) = mu/2 (tr C + 1 - 3) - mu ln J + lam/2 (ln J)^2            [J/m^3 per Pa]
    P(F)    = mu (F - F^-T) + lam ln J F^-T                             (first Piola-Kirchhoff)
    A(F)    = dP/dF:  A_iJkL = mu d_ik d_JL + (mu - lam ln J) Fi_Jk Fi_Li + lam Fi_Ji Fi_Lk

(``Fi = F^-1``). On an element with reference corners ``Xe``, 2x2 Gauss points
(weights ``w det J0``) and reference shape gradients ``G_aJ = dN_a/dX_J``,
the spatial gradients ``d_ai = sum_J G_aJ Fi_Ji`` give

    R_ai       = sum_g w det J0 [mu (G_a F^T)_i + (lam ln J - mu) d_ai]
    K_(ai)(bk) = sum_g w det J0 [mu d_ik G_a.G_b + (mu - lam ln J) d_ak d_bi + lam d_ai d_bk]

with node-interleaved dofs ``2 a + i`` as in :mod:`tofsi.fem.elasticity`.
As ``u -> 0``, ``K -> K0`` (the small-strain stiffness with the same ``lam, mu``)
and a rigid rotation ``F = R`` gives ``P = 0``.

Nearly void elements: the energy interpolation of Wang, Lazarov, Sigmund &
Jensen (2014, Comput. Methods Appl. Mech. Engrg. 276, 453-472). With the
element modulus ``E_e = E(rho_e)`` and ``g_e = g(rho_e)`` in [0, 1] (1: solid,
fully nonlinear; 0: void, linear) the element energy is

    W_e(u) = E_e [W_NL(g u) - W_L(g u) + W_L(u)],      W_L(u) = 1/2 u . K0 u,

so ``R_e = E_e [g R_NL(g u) + (1 - g^2) K0 u]``, ``K_e = E_e [g^2 K_NL(g u) + (1 - g^2) K0]`` and

    dR_e/drho_e = E'_e [g R_NL(g u) + (1 - g^2) K0 u] + E_e g'_e [R_NL(g u) + g K_NL(g u) u - 2 g K0 u].

``g = 1`` everywhere is plain SIMP at finite strain; ``g = 0`` is the linear
element exactly. Every function is complex-safe in ``u``, the modulus and
``g`` (complex-step checks); inversion is judged on the real part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.fem.geometry import jacobians
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions


@dataclass(frozen=True)
class NonlinearWeight:
    """The weight ``g(rho)`` of the nonlinear energy (Wang et al. 2014), a smoothed Heaviside::

        g(rho) = [tanh(beta rho0) + tanh(beta (rho - rho0))] / [tanh(beta rho0) + tanh(beta (1 - rho0))]

    ``g(0) = 0`` (void: linear), ``g(1) = 1`` (solid: neo-Hookean); ``threshold`` ``rho0``
    and ``sharpness`` ``beta`` (Wang et al.: 0.01 and 500).
    """

    threshold: float = 0.01
    sharpness: float = 500.0

    def __call__(self, rho):
        b, r0 = self.sharpness, self.threshold
        return (math.tanh(b * r0) + np.tanh(b * (np.asarray(rho) - r0))) / (math.tanh(b * r0) + math.tanh(b * (1 - r0)))

    def derivative(self, rho):
        b, r0 = self.sharpness, self.threshold
        t = np.exp(-2.0 * np.abs(b * (np.asarray(rho) - r0)))            # sech^2 z = 4 t / (1 + t)^2, no overflow
        return b * 4.0 * t / (1.0 + t) ** 2 / (math.tanh(b * r0) + math.tanh(b * (1 - r0)))


class ElementValues(NamedTuple):
    """One evaluation of a batch of elements; forces, tangents and energy are None when the
    nonlinear part inverts an element (``det F <= 0`` at a Gauss point: the energy is undefined)."""

    forces: np.ndarray | None        # (E, 8) [N/m]
    tangents: np.ndarray | None      # (E, 8, 8) [N/m^2] (None when not asked for)
    det_min: np.ndarray              # (E,) smallest det F of the nonlinear part
    energy: np.ndarray | None        # (E,) [J/m]


class NeoHookeanKernel:
    """Internal forces, tangents and energies of a fixed reference mesh of Q1 quads.

    Xe : reference corners ``(E, 4, 2)`` [m]; poisson_ratio : ``nu`` (the Lame
    parameters are per unit Young's modulus; moduli are per-element inputs);
    K0 : the small-strain stiffness per unit modulus ``(E, 8, 8)`` if already made.
    """

    def __init__(self, Xe: np.ndarray, poisson_ratio: float, K0: np.ndarray | None = None):
        points, weights = gauss_square(2)
        Xe = np.asarray(Xe, dtype=float)
        _, dN = shape_functions(1, points)                             # (G, 4, 2) reference gradients
        _, det0, inv = jacobians(Xe, points)                           # (E, G), (E, G, 2, 2): B = dxi/dX
        E, G = det0.shape
        self.n_elements, self.n_points = E, G
        grad = np.matmul(dN, inv)                                      # (E, G, 4, 2) G_aJ = dN_am B_mJ
        self.grad_rows = np.ascontiguousarray(grad.transpose(0, 2, 3, 1).reshape(E, 4, 2 * G))   # [e, a, (J, g)]
        self.pull = np.ascontiguousarray(inv.transpose(2, 3, 0, 1))    # B_mJ (2, 2, E, G), component first
        self.dN = np.ascontiguousarray(dN.transpose(2, 0, 1))          # dN_am as [m, g, a] (2, G, 4)
        self.dN_pairs = np.ascontiguousarray(np.einsum("gam,gbn->mngab", dN, dN).reshape(2, 2, G, 16))
        self.weight = det0 * weights                                   # (E, G) w det J0 [m^2]
        self.lam, self.mu = lame(1.0, poisson_ratio)
        self.K0 = element_stiffness(Xe, self.lam, self.mu) if K0 is None else K0   # (E, 8, 8) per unit modulus
        # sum_g w det J0 G_a.G_b (E, 4, 4) and sum_g w det J0 G_a (E, 4, 2): the constant parts of
        # mu sum_g w det J0 G_a F^T = mu (sum_g w det J0 G_a + gram U) and of the tangent
        self.gradient_gram = np.einsum("eg,egaJ,egbJ->eab", self.weight, grad, grad)
        self.gradient_integral = np.einsum("eg,egaJ->eaJ", self.weight, grad)

    # ---- the nonlinear element (per unit modulus) ---------------------------------------------
    def displacement_gradient(self, ue: np.ndarray) -> np.ndarray:
        """``H = grad_X u`` as ``(E, i, J, G)`` at the Gauss points of element displacements ``(E, 8)``."""
        E, G = self.n_elements, self.n_points
        U = np.asarray(ue).reshape(E, 4, 2)                           # (E, a, i)
        return np.matmul(U.swapaxes(1, 2), self.grad_rows).reshape(E, 2, 2, G)

    def deformation_gradient(self, ue: np.ndarray) -> np.ndarray:
        """``F = I + grad_X u`` ``(E, G, 2, 2)`` at the Gauss points of element displacements ``(E, 8)``."""
        F = self.displacement_gradient(ue).transpose(0, 3, 1, 2).copy()
        F[..., 0, 0] += 1.0
        F[..., 1, 1] += 1.0
        return F

    def nonlinear(self, ue: np.ndarray, tangent: bool = True) -> ElementValues:
        """Neo-Hookean internal forces, tangents (if ``tangent``), smallest ``det F`` and
        energies of element displacements ``ue`` ``(E, 8)``, per unit modulus.

        Gauss-point quantities are held component by component (``(E, G)`` arrays). With
        ``Q = B F^-1`` (so ``d_ai = sum_m dN_am Q_mi``) the sums over Gauss points and reference
        gradients are matrix products with the constant tables ``dN_am`` and ``dN_am dN_bn``
        (as :mod:`movers.yeoh_kernel`): ``sum_g c d_ai = sum_(g, m) (c Q_mi) dN_am`` and
        ``K_(ai)(bk) = sum_(m, n) sum_g [c1 Q_mk Q_ni + c2 Q_mi Q_nk] dN_am dN_bn + mu d_ik gram_ab``.
        """
        E, G = self.n_elements, self.n_points
        H = self.displacement_gradient(ue)
        F = [[1.0 + H[:, 0, 0], H[:, 0, 1]], [H[:, 1, 0], 1.0 + H[:, 1, 1]]]    # F[i][J] (E, G)
        J = F[0][0] * F[1][1] - F[0][1] * F[1][0]
        det_min = J.real.min(axis=1)
        if np.any(det_min <= 0.0):
            return ElementValues(None, None, det_min, None)
        lam, mu, wt = self.lam, self.mu, self.weight
        log_J = np.log(J)                                              # (E, G)
        trC = F[0][0] ** 2 + F[0][1] ** 2 + F[1][0] ** 2 + F[1][1] ** 2
        W = np.einsum("eg,eg->e", wt, 0.5 * mu * (trC - 2.0) - mu * log_J + 0.5 * lam * log_J ** 2)
        Fi = [[F[1][1] / J, -F[0][1] / J], [-F[1][0] / J, F[0][0] / J]]       # (F^-1)[J][i]
        B = self.pull
        Q = [[B[m, 0] * Fi[0][i] + B[m, 1] * Fi[1][i] for i in range(2)] for m in range(2)]   # Q[m][i]
        c = wt * (lam * log_J - mu)                                    # (E, G)
        U = np.asarray(ue).reshape(E, 4, 2)
        Re = mu * (self.gradient_integral + np.matmul(self.gradient_gram, U))        # (E, a, i)
        for i in range(2):
            Re[:, :, i] += (c * Q[0][i]) @ self.dN[0] + (c * Q[1][i]) @ self.dN[1]
        Re = Re.reshape(E, 8)
        if not tangent:
            return ElementValues(Re, None, det_min, W)
        # A[(i, k)] = c1 Q_mk Q_ni + c2 Q_mi Q_nk for (i, k) = 00, 01, 11 and each (m, n);
        # c1 = w (mu - lam ln J) = -c, c2 = w lam
        c1, c12 = -c, lam * wt - c
        K = np.zeros((3 * E, 16), dtype=J.dtype)                       # [((i, k), e), (a, b)]
        A = np.empty((3, E, G), dtype=J.dtype)
        for m in range(2):
            for n in range(2):
                A[0] = c12 * Q[m][0] * Q[n][0]
                A[1] = c1 * Q[m][1] * Q[n][0] + (c12 - c1) * Q[m][0] * Q[n][1]
                A[2] = c12 * Q[m][1] * Q[n][1]
                K += A.reshape(3 * E, G) @ self.dN_pairs[m, n]
        K00, K01, K11 = K.reshape(3, E, 4, 4)
        Ke = np.empty((E, 8, 8), dtype=J.dtype)
        Ke[:, 0::2, 0::2] = K00 + mu * self.gradient_gram
        Ke[:, 0::2, 1::2] = K01
        Ke[:, 1::2, 0::2] = K01.transpose(0, 2, 1)
        Ke[:, 1::2, 1::2] = K11 + mu * self.gradient_gram
        return ElementValues(Re, Ke, det_min, W)

    def nonlinear_energy(self, ue: np.ndarray) -> np.ndarray:
        """``int W_NL dV`` per element ``(E,)`` [J/m per Pa]; NaN where an element is inverted."""
        F = self.deformation_gradient(ue)
        J = F[..., 0, 0] * F[..., 1, 1] - F[..., 0, 1] * F[..., 1, 0]
        log_J = np.log(np.where(J.real > 0, J, np.nan))
        trC = np.einsum("egiJ,egiJ->eg", F, F)
        W = 0.5 * self.mu * (trC - 2.0) - self.mu * log_J + 0.5 * self.lam * log_J ** 2
        return np.einsum("eg,eg->e", self.weight, W)

    def linear_forces(self, ue: np.ndarray) -> np.ndarray:
        """``K0 u`` ``(E, 8)`` per unit modulus."""
        return np.einsum("eab,eb->ea", self.K0, ue)

    # ---- the energy-interpolated element ------------------------------------------------------
    def evaluate(self, ue: np.ndarray, modulus, g, tangent: bool = True) -> ElementValues:
        """Interpolated internal forces ``(E, 8)``, tangents ``(E, 8, 8)`` (if ``tangent``),
        smallest ``det F`` of the nonlinear part ``g u`` and energies ``W_e`` ``(E,)``.

        modulus : ``E(rho)`` ``(E,)`` [Pa]; g : ``g(rho)`` ``(E,)`` (ones: plain SIMP).
        """
        modulus, g = np.asarray(modulus), np.asarray(g)
        Rn, Kn, det_min, Wn = self.nonlinear(g[:, None] * ue, tangent)
        if Rn is None:
            return ElementValues(None, None, det_min, None)
        linear = 1.0 - g * g                                           # (E,)
        K0u = self.linear_forces(ue)
        Re = modulus[:, None] * (g[:, None] * Rn + linear[:, None] * K0u)
        We = modulus * (Wn + 0.5 * linear * np.einsum("ea,ea->e", ue, K0u))
        if not tangent:
            return ElementValues(Re, None, det_min, We)
        Kn *= (modulus * g * g)[:, None, None]                         # Kn is this call's own array
        Kn += (modulus * linear)[:, None, None] * self.K0
        return ElementValues(Re, Kn, det_min, We)

    def density_vectors(self, ue: np.ndarray, modulus, dmodulus, g, dg) -> np.ndarray:
        """``dR_e/drho_e`` ``(E, 8)`` from ``E(rho)``, ``E'(rho)``, ``g(rho)``, ``g'(rho)`` ``(E,)``
        (the formula in the module docstring); NaN where the nonlinear part is inverted."""
        modulus, dmodulus, g, dg = (np.asarray(a) for a in (modulus, dmodulus, g, dg))
        Rn, Kn, _, _ = self.nonlinear(g[:, None] * ue)
        if Rn is None:
            return np.full(np.shape(ue), np.nan)
        K0u = self.linear_forces(ue)
        Knu = np.einsum("eab,eb->ea", Kn, ue)
        forces = g[:, None] * Rn + (1.0 - g * g)[:, None] * K0u
        return dmodulus[:, None] * forces + (modulus * dg)[:, None] * (Rn + g[:, None] * (Knu - 2.0 * K0u))

    def energy(self, ue: np.ndarray, modulus, g) -> np.ndarray:
        """Element strain energy ``W_e(u)`` ``(E,)`` [J/m]: ``E [W_NL(g u) - W_L(g u) + W_L(u)]``."""
        modulus, g = np.asarray(modulus), np.asarray(g)
        W_L = 0.5 * np.einsum("ea,ea->e", ue, self.linear_forces(ue))
        return modulus * (self.nonlinear_energy(g[:, None] * ue) + (1.0 - g * g) * W_L)
