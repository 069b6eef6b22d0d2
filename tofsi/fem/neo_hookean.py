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

import numpy as np

from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.fem.geometry import inverse_2x2, physical_gradients
from tofsi.fem.quadrature import gauss_square


class NeoHookeanKernel:
    """Internal forces, tangents and energies of a fixed reference mesh of Q1 quads.

    Xe : reference corners ``(E, 4, 2)`` [m]; poisson_ratio : ``nu`` (the Lame
    parameters are per unit Young's modulus; moduli are per-element inputs).
    """

    def __init__(self, Xe: np.ndarray, poisson_ratio: float):
        points, weights = gauss_square(2)
        grad, det0 = physical_gradients(np.asarray(Xe, dtype=float), 1, points)   # (E, G, 4, 2), (E, G)
        self.grad = grad
        self.weight = det0 * weights                                   # (E, G) w det J0 [m^2]
        self.n_elements = grad.shape[0]
        self.lam, self.mu = lame(1.0, poisson_ratio)
        self.K0 = element_stiffness(Xe, self.lam, self.mu)             # (E, 8, 8) per unit modulus
        # the constant part mu d_ik sum_g w det J0 G_a . G_b of the tangent, (E, 4, 4)
        self.gradient_gram = np.einsum("eg,egaJ,egbJ->eab", self.weight, grad, grad)

    # ---- the nonlinear element (per unit modulus) ---------------------------------------------
    def deformation_gradient(self, ue: np.ndarray) -> np.ndarray:
        """``F = I + grad_X u`` ``(E, G, 2, 2)`` at the Gauss points of element displacements ``(E, 8)``."""
        U = np.asarray(ue).reshape(-1, 4, 2)                          # (E, a, i)
        F = np.einsum("eai,egaJ->egiJ", U, self.grad)                  # (E, G, i, J)
        F[..., 0, 0] += 1.0
        F[..., 1, 1] += 1.0
        return F

    def nonlinear(self, ue: np.ndarray, tangent: bool = True):
        """Neo-Hookean internal forces ``(E, 8)``, tangents ``(E, 8, 8)`` (or None) and the smallest
        ``det F`` per element ``(E,)``; forces and tangents are None when an element is inverted
        (``det F <= 0`` at a Gauss point: the energy is undefined there)."""
        F = self.deformation_gradient(ue)
        J, Fi = inverse_2x2(F)                                         # (E, G), (E, G, 2, 2)
        det_min = J.real.min(axis=1)
        if np.any(det_min <= 0.0):
            return None, None, det_min
        lam, mu, wt = self.lam, self.mu, self.weight
        log_J = np.log(J)                                              # (E, G)
        d = np.matmul(self.grad, Fi)                                   # (E, G, 4, 2) spatial gradients
        GF = np.matmul(self.grad, F.swapaxes(-1, -2))                  # (E, G, 4, 2) (G_a F^T)_i
        c = wt * (lam * log_J - mu)                                    # (E, G)
        Re = np.einsum("eg,egai->eai", mu * wt, GF) + np.einsum("eg,egai->eai", c, d)
        Re = Re.reshape(-1, 8)
        if not tangent:
            return Re, None, det_min
        E, G = J.shape
        D = d.reshape(E, G, 8)                                         # [(a, i)]
        DD_swap = np.matmul((D * (-c)[..., None]).swapaxes(1, 2), D)   # sum_g (mu - lam ln J) d_ai d_bk
        DD = np.matmul((D * (lam * wt)[..., None]).swapaxes(1, 2), D)  # sum_g lam d_ai d_bk
        K = DD.reshape(E, 4, 2, 4, 2) + DD_swap.reshape(E, 4, 2, 4, 2).transpose(0, 1, 4, 3, 2)
        K[:, :, 0, :, 0] += mu * self.gradient_gram
        K[:, :, 1, :, 1] += mu * self.gradient_gram
        return Re, K.reshape(E, 8, 8), det_min

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
    def evaluate(self, ue: np.ndarray, modulus, g, tangent: bool = True):
        """Interpolated internal forces ``(E, 8)``, tangents ``(E, 8, 8)`` (or None) and the smallest
        ``det F`` of the nonlinear part ``g u`` per element ``(E,)``.

        modulus : ``E(rho)`` ``(E,)`` [Pa]; g : ``g(rho)`` ``(E,)`` (ones: plain SIMP).
        Forces and tangents are None when the nonlinear part inverts an element.
        """
        modulus, g = np.asarray(modulus), np.asarray(g)
        Rn, Kn, det_min = self.nonlinear(g[:, None] * ue, tangent)
        if Rn is None:
            return None, None, det_min
        linear = 1.0 - g * g                                           # (E,)
        Re = modulus[:, None] * (g[:, None] * Rn + linear[:, None] * self.linear_forces(ue))
        if not tangent:
            return Re, None, det_min
        Ke = modulus[:, None, None] * ((g * g)[:, None, None] * Kn + linear[:, None, None] * self.K0)
        return Re, Ke, det_min

    def density_vectors(self, ue: np.ndarray, modulus, dmodulus, g, dg) -> np.ndarray:
        """``dR_e/drho_e`` ``(E, 8)`` from ``E(rho)``, ``E'(rho)``, ``g(rho)``, ``g'(rho)`` ``(E,)``
        (the formula in the module docstring); NaN where the nonlinear part is inverted."""
        modulus, dmodulus, g, dg = (np.asarray(a) for a in (modulus, dmodulus, g, dg))
        Rn, Kn, det_min = self.nonlinear(g[:, None] * ue)
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
