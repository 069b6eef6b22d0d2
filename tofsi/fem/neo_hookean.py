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

Nearly void elements: the energy interpolation of Wang et al. (2014), shared
with every material kernel (:mod:`tofsi.fem.hyperelastic`, which this module
re-exports :class:`NonlinearWeight` and :class:`ElementValues` from).
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.hyperelastic import ElementValues, HyperelasticKernel, NonlinearWeight

__all__ = ["ElementValues", "NeoHookeanKernel", "NonlinearWeight"]


class NeoHookeanKernel(HyperelasticKernel):
    """Internal forces, tangents and energies of a fixed reference mesh of Q1 quads.

    Xe : reference corners ``(E, 4, 2)`` [m]; poisson_ratio : ``nu`` (the Lame
    parameters are per unit Young's modulus; moduli are per-element inputs);
    K0 : the small-strain stiffness per unit modulus ``(E, 8, 8)`` if already made.
    """

    material = "neo-Hookean"

    def __init__(self, Xe: np.ndarray, poisson_ratio: float, K0: np.ndarray | None = None):
        super().__init__(Xe, poisson_ratio, K0)
        dN, inv, grad, G = self.shape_gradients, self.inverse_jacobians, self.grad, self.n_points
        self.pull = np.ascontiguousarray(inv.transpose(2, 3, 0, 1))    # B_mJ (2, 2, E, G), component first
        self.dN = np.ascontiguousarray(dN.transpose(2, 0, 1))          # dN_am as [m, g, a] (2, G, 4)
        self.dN_pairs = np.ascontiguousarray(np.einsum("gam,gbn->mngab", dN, dN).reshape(2, 2, G, 16))
        # sum_g w det J0 G_a.G_b (E, 4, 4) and sum_g w det J0 G_a (E, 4, 2): the constant parts of
        # mu sum_g w det J0 G_a F^T = mu (sum_g w det J0 G_a + gram U) and of the tangent
        self.gradient_gram = np.einsum("eg,egaJ,egbJ->eab", self.weight, grad, grad)
        self.gradient_integral = np.einsum("eg,egaJ->eaJ", self.weight, grad)

    # ---- the nonlinear element (per unit modulus) ---------------------------------------------
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
