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

Shape derivative of the forces ``f = K(P) v`` for a fixed ``v`` (what the
derivatives of a motion in increments on the updated mesh need,
``D = df/dP`` (6, 6) per triangle, row a force dof, column a coordinate):
per edge ``d = P_q - P_p`` with ``delta = v_q - v_p`` the lineal force on ``q``
is ``g = (d . delta) d / (2 L^3)`` (minus it on ``p``), so

    dg/dd = (d delta^T + (d . delta) I - 3 (d . delta) d d^T / L^2) / (2 L^3);

the torsional forces ``sum_r C_r w_r R_r`` (``w_r = R_r . v``, ``R_r`` the
gradient of the angle ``theta_r``) give

    D_T = sum_r C_r w_r H_r + w_r R_r (grad C_r)^T + C_r R_r (H_r v)^T,

``H_r`` the Hessian of ``theta_i = phi(P_k - P_i) - phi(P_j - P_i)``,
``phi(d)`` the polar angle, ``hess phi = [[2 d_x d_y, d_y^2 - d_x^2],
[d_y^2 - d_x^2, -2 d_x d_y]] / L^4``, and
``grad C_r = C_r (grad L_ij^2 / L_ij^2 + grad L_ik^2 / L_ik^2 - 2 grad(2A) / 2A)``.
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


def _angle_parts(P: np.ndarray):
    """Per corner ``r`` of triangles ``P`` ``(T, 3, 2)``: the angle gradient ``R (T, 3, 6)``, its
    Hessian ``H (T, 3, 6, 6)``, ``C (T, 3)`` and ``grad C (T, 3, 6)``."""
    T = P.shape[0]
    x, y = P[..., 0], P[..., 1]
    area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    grad_area2 = np.stack([y[:, 1] - y[:, 2], x[:, 2] - x[:, 1], y[:, 2] - y[:, 0], x[:, 0] - x[:, 2],
                           y[:, 0] - y[:, 1], x[:, 1] - x[:, 0]], axis=1)          # (T, 6)
    R = np.zeros((T, 3, 6))
    H = np.zeros((T, 3, 6, 6))
    C = np.empty((T, 3))
    dC = np.zeros((T, 3, 6))
    for r, (i, j, k) in enumerate(((0, 1, 2), (1, 2, 0), (2, 0, 1))):
        ii, jj, kk = slice(2 * i, 2 * i + 2), slice(2 * j, 2 * j + 2), slice(2 * k, 2 * k + 2)
        for q, qq, sign in ((k, kk, 1.0), (j, jj, -1.0)):       # theta_i = phi(d_ik) - phi(d_ij)
            d = P[:, q] - P[:, i]
            L2 = np.einsum("ti,ti->t", d, d)
            grad = sign * np.stack([-d[:, 1], d[:, 0]], axis=1) / L2[:, None]
            R[:, r, qq] += grad
            R[:, r, ii] -= grad
            dx, dy = d[:, 0], d[:, 1]
            hess = sign * np.stack([np.stack([2 * dx * dy, dy**2 - dx**2], -1),
                                    np.stack([dy**2 - dx**2, -2 * dx * dy], -1)], -2) / (L2**2)[:, None, None]
            H[:, r, qq, qq] += hess
            H[:, r, ii, ii] += hess
            H[:, r, ii, qq] -= hess
            H[:, r, qq, ii] -= hess
            dC[:, r, qq] += 2 * d / L2[:, None]                  # grad L^2 / L^2
            dC[:, r, ii] -= 2 * d / L2[:, None]
        dij, dik = P[:, j] - P[:, i], P[:, k] - P[:, i]
        C[:, r] = np.einsum("ti,ti->t", dij, dij) * np.einsum("ti,ti->t", dik, dik) / area2**2
        dC[:, r] = C[:, r, None] * (dC[:, r] - 2 * grad_area2 / area2[:, None])
    return R, H, C, dC


def triangle_force_derivative(P: np.ndarray, v: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """``d(K(P) v)/dP`` ``(T, 6, 6)`` of triangles ``P`` ``(T, 3, 2)`` for vertex motions ``v``
    ``(T, 6)`` held fixed (real ``P``; module docstring)."""
    T = P.shape[0]
    D = np.zeros((T, 6, 6))
    for p, q in ((0, 1), (1, 2), (2, 0)):
        d = P[:, q] - P[:, p]
        delta = v[:, 2 * q:2 * q + 2] - v[:, 2 * p:2 * p + 2]
        L2 = np.einsum("ti,ti->t", d, d)
        dd = np.einsum("ti,ti->t", d, delta)
        G = (np.einsum("ti,tj->tij", d, delta) + dd[:, None, None] * np.eye(2)
             - 3 * (dd / L2)[:, None, None] * np.einsum("ti,tj->tij", d, d)) / (2 * L2**1.5)[:, None, None]
        ip, iq = slice(2 * p, 2 * p + 2), slice(2 * q, 2 * q + 2)
        D[:, iq, iq] += G
        D[:, ip, ip] += G
        D[:, iq, ip] -= G
        D[:, ip, iq] -= G
    if torsion_scale == 0.0:
        return D
    R, H, C, dC = _angle_parts(P)
    w = np.einsum("tri,ti->tr", R, v)
    Hv = np.einsum("trij,tj->tri", H, v)
    D_T = (np.einsum("tr,trij->tij", C * w, H) + np.einsum("tr,tri,trj->tij", w, R, dC)
           + np.einsum("tr,tri,trj->tij", C, R, Hv))
    return D + torsion_scale * D_T


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


def quad_force_derivative(Xe: np.ndarray, v: np.ndarray, diagonal: np.ndarray,
                          torsion_scale: float = 1.0) -> np.ndarray:
    """``d(quad_stiffness(Xe) v)/dXe`` ``(E, 8, 8)`` (last axis the corner coordinate ``2 a + i``)
    for quad motions ``v`` ``(E, 8)`` held fixed; ``diagonal`` as :func:`quad_stiffness`."""
    D = np.zeros((Xe.shape[0], 8, 8))
    for code, name in enumerate(("1-3", "2-4")):
        weight = np.where(diagonal == code, 1.0, np.where(diagonal == 2, 0.5, 0.0))
        use = weight > 0
        if not use.any():
            continue
        Xu, vu = Xe[use], v[use]
        Du = 0.0
        for tri in TRIANGLES[name]:
            S = _SELECT[tri]
            Du = Du + np.matmul(np.matmul(S.T, triangle_force_derivative(Xu[:, tri, :], vu @ S.T,
                                                                         torsion_scale)), S)
        D[use] += weight[use, None, None] * Du
    return D
