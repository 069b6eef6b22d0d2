"""Plane-strain Saint Venant-Kirchhoff elements on Q1 quads (total Lagrangian, batched).

The material of Turek & Hron's FSI benchmark (2006): linear elasticity in the
Green-Lagrange strain. Per unit Young's modulus (``lam, mu`` =
:func:`~tofsi.fem.elasticity.lame` of ``(1, nu)``), with ``F = I + grad_X u`` the
2x2 deformation gradient (plane strain: ``F33 = 1``, so ``E33 = 0``),
``E = (F^T F - I) / 2``::

    W_NL(F) = lam/2 (tr E)^2 + mu E:E                     [J/m^3 per Pa]
    S       = lam tr(E) I + 2 mu E                        (second Piola-Kirchhoff)
    P       = F S                                         (first Piola-Kirchhoff)
    A(F)    = dP/dF:  A_iJkL = d_ik S_JL + lam F_iJ F_kL + mu (F_iL F_kJ + (F F^T)_ik d_JL)

On an element with 2x2 Gauss points (weights ``w det J0``) and reference shape
gradients ``G_aJ = dN_a/dX_J``, with ``d_ai = (F G_a)_i`` (the variation of the
strain's trace per unit displacement of dof ``a i``)::

    R_ai       = sum_g w det J0 (F S G_a)_i
    K_(ai)(bk) = sum_g w det J0 [d_ik G_a.S G_b + lam d_ai d_bk + mu d_ak d_bi + mu (F F^T)_ik G_a.G_b]

with node-interleaved dofs ``2 a + i`` as in :mod:`tofsi.fem.elasticity`. At
``u = 0`` the tangent is the small-strain stiffness ``K0``; a rigid rotation
(``E = 0``) is stress free. Unlike neo-Hookean, the energy stays finite as
``det F -> 0`` (Saint Venant-Kirchhoff softens in strong compression): an
element whose ``det F <= 0`` at a Gauss point is still reported as inverted
(no physical state), as for every material. Nearly void elements by the
energy interpolation of :mod:`tofsi.fem.hyperelastic`. Complex-safe in ``u``.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.hyperelastic import ElementValues, HyperelasticKernel


class SaintVenantKirchhoffKernel(HyperelasticKernel):
    """Saint Venant-Kirchhoff internal forces, tangents and energies of a fixed reference mesh of
    Q1 quads (see the module docstring; constructor as :class:`HyperelasticKernel`)."""

    material = "Saint Venant-Kirchhoff"

    def _strains(self, ue: np.ndarray):
        """``F`` ``(E, G, 2, 2)``, ``det F`` and the Green-Lagrange strain ``E`` ``(E, G, 2, 2)``."""
        F = self.deformation_gradient(ue)
        J = F[..., 0, 0] * F[..., 1, 1] - F[..., 0, 1] * F[..., 1, 0]
        strain = 0.5 * np.matmul(F.swapaxes(-1, -2), F)
        strain[..., 0, 0] -= 0.5
        strain[..., 1, 1] -= 0.5
        return F, J, strain

    def _density(self, strain: np.ndarray) -> np.ndarray:
        """``W_NL`` per unit modulus at the Gauss points ``(E, G)``."""
        trace = strain[..., 0, 0] + strain[..., 1, 1]
        return 0.5 * self.lam * trace ** 2 + self.mu * np.einsum("egIJ,egIJ->eg", strain, strain)

    def nonlinear(self, ue: np.ndarray, tangent: bool = True) -> ElementValues:
        """Internal forces ``(E, 8)``, tangents ``(E, 8, 8)`` (if ``tangent``), smallest ``det F``
        and energies of element displacements ``ue`` ``(E, 8)``, per unit modulus."""
        E = self.n_elements
        F, J, strain = self._strains(ue)
        det_min = J.real.min(axis=1)
        if np.any(det_min <= 0.0):
            return ElementValues(None, None, det_min, None)
        lam, mu, wt, G_ = self.lam, self.mu, self.weight, self.grad
        W = np.einsum("eg,eg->e", wt, self._density(strain))
        S = 2.0 * mu * strain
        trace = strain[..., 0, 0] + strain[..., 1, 1]
        S[..., 0, 0] += lam * trace
        S[..., 1, 1] += lam * trace
        FS = np.matmul(F, S) * wt[..., None, None]                      # w det J0 P (E, G, i, J)
        Re = np.einsum("egaJ,egiJ->eai", G_, FS).reshape(E, 8)
        if not tangent:
            return ElementValues(Re, None, det_min, W)
        d = np.einsum("egiJ,egaJ->egai", F, G_)                         # (F G_a)_i (E, G, 4, 2)
        wd = d * wt[..., None, None]
        geometric = np.einsum("egaJ,egJL,egbL->eab", G_, S * wt[..., None, None], G_)
        gram = np.einsum("egaJ,egbJ->egab", G_, G_)                     # G_a.G_b (E, G, 4, 4)
        FFt = np.matmul(F, F.swapaxes(-1, -2)) * (mu * wt)[..., None, None]
        K = lam * np.einsum("egai,egbk->eaibk", wd, d) + mu * np.einsum("egak,egbi->eaibk", wd, d)
        K += np.einsum("egik,egab->eaibk", FFt, gram)
        K[:, :, 0, :, 0] += geometric
        K[:, :, 1, :, 1] += geometric
        return ElementValues(Re, K.reshape(E, 8, 8), det_min, W)

    def nonlinear_energy(self, ue: np.ndarray) -> np.ndarray:
        """``int W_NL dV`` per element ``(E,)`` [J/m per Pa]; NaN where an element is inverted."""
        _, J, strain = self._strains(ue)
        W = np.einsum("eg,eg->e", self.weight, self._density(strain))
        return np.where(J.real.min(axis=1) > 0, W, np.nan)
