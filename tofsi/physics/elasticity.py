"""Plane-strain linear elasticity on Q1 quads (batched element kernels).

Strains in Voigt form ``[eps_xx, eps_yy, 2 eps_xy] = B u_e`` with the
node-interleaved element displacement ``u_e = [u0x, u0y, ..., u3x, u3y]``.
Plane strain: ``sigma = D eps`` with

    D = E / ((1 + nu)(1 - 2 nu)) [[1 - nu, nu, 0], [nu, 1 - nu, 0], [0, 0, (1 - 2 nu)/2]].

The element stiffness ``K_e = sum_g w_g B^T D B det J_g^(1 - chi)`` uses
2x2 Gauss points; ``chi > 0`` is Jacobian-based stiffening (Stein,
Tezduyar & Benney 2003): small elements become relatively stiffer.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.assembly import weighted_gram
from tofsi.fem.geometry import physical_gradients
from tofsi.fem.quadrature import gauss_square


def plane_strain_matrix(youngs_modulus: float, poisson_ratio: float) -> np.ndarray:
    """Constitutive matrix ``D`` ``(3, 3)`` [Pa]."""
    nu = poisson_ratio
    c = youngs_modulus / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return c * np.array([[1 - nu, nu, 0.0], [nu, 1 - nu, 0.0], [0.0, 0.0, (1 - 2 * nu) / 2]])


def strain_matrix(grad: np.ndarray) -> np.ndarray:
    """``B`` ``(..., 3, 2k)`` from basis gradients ``grad`` ``(..., k, 2)``."""
    k = grad.shape[-2]
    B = np.zeros(grad.shape[:-2] + (3, 2 * k), dtype=grad.dtype)
    B[..., 0, 0::2] = grad[..., 0]
    B[..., 1, 1::2] = grad[..., 1]
    B[..., 2, 0::2] = grad[..., 1]
    B[..., 2, 1::2] = grad[..., 0]
    return B


def element_stiffness(Xe: np.ndarray, D: np.ndarray, scale=1.0, chi: float = 0.0) -> np.ndarray:
    """Stiffness ``(E, 8, 8)`` of quads with corners ``Xe`` ``(E, 4, 2)``.

    scale : per-element factor ``(E,)`` (SIMP modulus ratio, stiffening factors)
    chi : Jacobian stiffening power; the integrand weight is ``det J^(1 - chi)``
    """
    points, weights = gauss_square(2)
    grad, det = physical_gradients(Xe, 1, points)          # (E, G, 4, 2), (E, G)
    B = strain_matrix(grad)                                # (E, G, 3, 8)
    w = weights * (det if chi == 0.0 else det ** (1.0 - chi))
    Ke = weighted_gram(B, D @ B, w)
    return Ke * np.asarray(scale)[..., None, None] if np.ndim(scale) else Ke * scale
