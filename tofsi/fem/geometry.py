"""The bilinear geometry map of a batch of quads and its derivatives.

Geometry is always the Q1 map of the 4 corner coordinates ``Xe`` ``(E, 4, 2)``;
the functions accept complex coordinates so that shape derivatives can be
taken by the complex step.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.shapes import shape_functions, shape_hessians


def inverse_2x2(A: np.ndarray):
    """Determinants ``(...)`` and inverses ``(..., 2, 2)`` of a stack of 2x2 matrices."""
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    inv = np.empty_like(A)
    inv[..., 0, 0] = A[..., 1, 1] / det
    inv[..., 1, 1] = A[..., 0, 0] / det
    inv[..., 0, 1] = -A[..., 0, 1] / det
    inv[..., 1, 0] = -A[..., 1, 0] / det
    return det, inv


def jacobians(Xe: np.ndarray, points: np.ndarray):
    """Jacobian ``J[e, g] = dx/dxi`` ``(E, G, 2, 2)``, its determinant and inverse.

    ``J[e, g, i, a] = sum_k Xe[e, k, i] dN1_k/dxi_a``; ``Jinv`` maps reference
    gradients to physical ones: ``grad N = dN_ref @ Jinv``.
    """
    _, dN1 = shape_functions(1, points)                     # (G, 4, 2)
    J = np.tensordot(Xe, dN1, axes=([1], [1])).transpose(0, 2, 1, 3)   # (E, G, 2, 2)
    det, inv = inverse_2x2(J)
    return J, det, inv


def physical_gradients(Xe: np.ndarray, degree: int, points: np.ndarray):
    """Gradients ``(E, G, k, 2)`` of the degree-``degree`` basis and ``det J`` ``(E, G)``."""
    _, dN = shape_functions(degree, points)                 # (G, k, 2)
    _, det, inv = jacobians(Xe, points)
    grad = np.matmul(dN, inv)                               # (E, G, k, 2)
    return grad, det


def map_points(Xe: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Physical coordinates ``(E, G, 2)`` of reference points ``(G, 2)``."""
    N1, _ = shape_functions(1, points)
    return np.matmul(N1, Xe)


def physical_hessians(Xe: np.ndarray, degree: int, points: np.ndarray, grad=None):
    """Second derivatives ``(E, G, k, 2, 2)`` of the basis on the bilinear map.

    ``d2N/dx_i dx_j = Jinv_ai Jinv_bj (d2N/dxi_a dxi_b - sum_m dN/dx_m d2x_m/dxi_a dxi_b)``;
    only the mixed second derivative of a bilinear map is non-zero. The 2x2
    products are written out (fast for real and complex inputs alike).
    """
    H_ref = shape_hessians(degree, points)                  # (G, k, 2, 2)
    _, _, inv = jacobians(Xe, points)
    if grad is None:
        grad, _ = physical_gradients(Xe, degree, points)
    _, dN1 = shape_functions(1, points)
    # d2x_m / dxi deta of the bilinear map (constant per element): sum_k Xe[k, m] * (a_k b_k / 4)
    mixed = 0.25 * (Xe[:, 0] - Xe[:, 1] + Xe[:, 2] - Xe[:, 3])               # (E, 2)
    C = np.broadcast_to(H_ref, grad.shape[:2] + H_ref.shape[1:]).astype(np.result_type(Xe, float))
    corr = grad[..., 0] * mixed[:, None, None, 0] + grad[..., 1] * mixed[:, None, None, 1]  # (E, G, k)
    c00, c11 = C[..., 0, 0], C[..., 1, 1]
    c01 = C[..., 0, 1] - corr                                # the mixed entry of a bilinear map
    i00, i01 = inv[..., 0, 0, None], inv[..., 0, 1, None]    # (E, G, 1)
    i10, i11 = inv[..., 1, 0, None], inv[..., 1, 1, None]
    # H_ij = sum_ab inv_ai C_ab inv_bj, C symmetric
    h00 = i00 * (c00 * i00 + c01 * i10) + i10 * (c01 * i00 + c11 * i10)
    h01 = i00 * (c00 * i01 + c01 * i11) + i10 * (c01 * i01 + c11 * i11)
    h11 = i01 * (c00 * i01 + c01 * i11) + i11 * (c01 * i01 + c11 * i11)
    return np.stack([np.stack([h00, h01], -1), np.stack([h01, h11], -1)], -2)
