"""Farhat et al. (1998) lineal + torsional spring stiffness of triangles and quads.

Triangle ``ijk`` with current vertex coordinates. Lineal springs along its
edges, stiffness ``1/L`` (unit area and modulus); an interior edge is shared
by two triangles, so each triangle contributes half, and every edge of the
triangulation ends up with exactly ``1/L``:

    K_L = (1/2) sum_edges (1/L) [[n n^T, -n n^T], [-n n^T, n n^T]]

Torsional springs at the vertices, ``C_i = L_ij^2 L_ik^2 / (4 A^2)``
(= 1 / sin^2 theta_i), ``K_T = R^T diag(C_i, C_j, C_k) R`` where row ``i`` of
``R`` is the gradient of the angle at ``i`` with respect to the dofs
``(x_i, y_i, x_j, y_j, x_k, y_k)``:

    R_i = [b_ik - b_ij, a_ij - a_ik, b_ij, -a_ij, -b_ik, a_ik],
    a_pq = (x_q - x_p) / L_pq^2,  b_pq = (y_q - y_p) / L_pq^2,

and rows ``j``, ``k`` follow by cyclic permutation. The triangle matrix is
``K_L + TSC K_T``. Lineal stiffness scales as 1/length and torsional as
1/length^2, so scaling the geometry by GSC is the same as TSC = 1/GSC.

A quad is split along diagonal 1-3 (triangles 012, 023), 2-4 (013, 123), or
both (the mean of the two); its 8x8 matrix is the sum of its triangles'.
"""

from __future__ import annotations

import numpy as np

DIAGONALS = ("1-3", "2-4", "both")
TRIANGLES = {"1-3": ((0, 1, 2), (0, 2, 3)), "2-4": ((0, 1, 3), (1, 2, 3))}


def triangle_stiffness(P: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """Spring stiffness ``(T, 6, 6)`` of triangles with vertices ``P`` ``(T, 3, 2)``."""
    T = P.shape[0]
    K = np.zeros((T, 6, 6), dtype=P.dtype)
    # lineal springs on the three edges
    for p, q in ((0, 1), (1, 2), (2, 0)):
        d = P[:, q] - P[:, p]
        L = np.sqrt(np.einsum("ti,ti->t", d, d))
        nn = np.einsum("ti,tj->tij", d, d) / L[:, None, None] ** 3     # (n n^T) / L
        blk = 0.5 * nn
        ip, iq = slice(2 * p, 2 * p + 2), slice(2 * q, 2 * q + 2)
        K[:, ip, ip] += blk
        K[:, iq, iq] += blk
        K[:, ip, iq] -= blk
        K[:, iq, ip] -= blk
    if torsion_scale == 0.0:
        return K
    # torsional springs: R (T, 3, 6) and C (T, 3)
    x, y = P[..., 0], P[..., 1]
    area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    R = np.zeros((T, 3, 6), dtype=P.dtype)
    C = np.empty((T, 3), dtype=P.dtype)
    for r, (i, j, k) in enumerate(((0, 1, 2), (1, 2, 0), (2, 0, 1))):
        dij, dik = P[:, j] - P[:, i], P[:, k] - P[:, i]
        Lij2, Lik2 = np.einsum("ti,ti->t", dij, dij), np.einsum("ti,ti->t", dik, dik)
        a_ij, b_ij = dij[:, 0] / Lij2, dij[:, 1] / Lij2
        a_ik, b_ik = dik[:, 0] / Lik2, dik[:, 1] / Lik2
        R[:, r, 2 * i] = b_ik - b_ij
        R[:, r, 2 * i + 1] = a_ij - a_ik
        R[:, r, 2 * j] = b_ij
        R[:, r, 2 * j + 1] = -a_ij
        R[:, r, 2 * k] = -b_ik
        R[:, r, 2 * k + 1] = a_ik
        C[:, r] = Lij2 * Lik2 / area2**2            # L_ij^2 L_ik^2 / (4 A^2), 2A = area2
    K += torsion_scale * np.einsum("tri,tr,trj->tij", R, C, R)
    return K


_SELECT = {tri: np.eye(8)[np.ravel([(2 * a, 2 * a + 1) for a in tri])]
           for name in TRIANGLES for tri in TRIANGLES[name]}


def quad_stiffness(Xe: np.ndarray, diagonal: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """Spring stiffness ``(E, 8, 8)`` of quads ``Xe`` ``(E, 4, 2)``.

    diagonal : (E,) codes 0 = "1-3", 1 = "2-4", 2 = "both"
    """
    E = Xe.shape[0]
    K = np.zeros((E, 8, 8), dtype=Xe.dtype)
    weight = {0: np.where(diagonal == 0, 1.0, np.where(diagonal == 2, 0.5, 0.0)),
              1: np.where(diagonal == 1, 1.0, np.where(diagonal == 2, 0.5, 0.0))}
    for code, name in enumerate(("1-3", "2-4")):
        use = weight[code] > 0
        if not use.any():
            continue
        Xu = Xe[use]
        Ku = 0.0
        for tri in TRIANGLES[name]:
            S = _SELECT[tri]                                   # (6, 8) triangle dofs -> quad dofs
            Ku = Ku + np.matmul(np.matmul(S.T, triangle_stiffness(Xu[:, tri, :], torsion_scale)), S)
        K[use] += weight[code][use, None, None] * Ku
    return K
