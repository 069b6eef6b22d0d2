"""Plane-strain linear elasticity on Q1 quads (batched element kernels).

Isotropic material with Lame parameters ``lam``, ``mu`` (plane strain uses the
3D values: ``lam = E nu / ((1 + nu)(1 - 2 nu))``, ``mu = E / (2 (1 + nu))``)::

    K_(a i)(b j) = sum_g w_g J_g^(1 - chi) [lam g_ai g_bj + mu g_aj g_bi + mu delta_ij g_a . g_b]

with ``g_a`` the physical gradient of corner ``a`` and node-interleaved dofs
``2 a + i``. All gradient-pair integrals ``M_(a k)(b l) = sum_g w J g_ak g_bl``
come from one batched matrix product. ``chi > 0`` is Jacobian-based
stiffening (Stein, Tezduyar & Benney 2003): small elements become relatively
stiffer. 2x2 Gauss points integrate the stiffness of parallelograms exactly.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.geometry import physical_gradients
from tofsi.fem.quadrature import gauss_square


def lame(youngs_modulus: float, poisson_ratio: float) -> tuple[float, float]:
    """Lame parameters ``(lam, mu)`` [Pa]."""
    nu = poisson_ratio
    return (youngs_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            youngs_modulus / (2.0 * (1.0 + nu)))


def gradient_products(Xe: np.ndarray, chi: float = 0.0) -> np.ndarray:
    """``M[e, a, k, b, l] = sum_g w_g J_g^(1 - chi) g_ak g_bl`` ``(E, 4, 2, 4, 2)``."""
    points, weights = gauss_square(2)
    grad, det = physical_gradients(Xe, 1, points)          # (E, G, 4, 2), (E, G)
    E, G = det.shape
    w = weights * (det if chi == 0.0 else det ** (1.0 - chi))
    g = grad.reshape(E, G, 8)
    M = np.matmul((g * w[:, :, None]).transpose(0, 2, 1), g)
    return M.reshape(E, 4, 2, 4, 2)


def element_stiffness(Xe: np.ndarray, lam: float, mu: float, scale=1.0, chi: float = 0.0) -> np.ndarray:
    """Stiffness ``(E, 8, 8)`` of quads with corners ``Xe`` ``(E, 4, 2)``.

    scale : per-element factor ``(E,)`` (SIMP modulus ratio, stiffening factors)
    chi : Jacobian stiffening power; the integrand weight is ``det J^(1 - chi)``
    """
    M = gradient_products(Xe, chi)
    K = lam * M + mu * M.transpose(0, 1, 4, 3, 2)
    trace = M[:, :, 0, :, 0] + M[:, :, 1, :, 1]                # (E, 4, 4)
    K[:, :, 0, :, 0] += mu * trace
    K[:, :, 1, :, 1] += mu * trace
    K = K.reshape(-1, 8, 8)
    return K * np.asarray(scale)[..., None, None] if np.ndim(scale) else K * scale

