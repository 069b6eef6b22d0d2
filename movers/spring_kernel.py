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
import scipy.sparse as sp

DIAGONALS = ("1-3", "2-4", "both")
TRIANGLES = {"1-3": ((0, 1, 2), (0, 2, 3)), "2-4": ((0, 1, 3), (1, 2, 3))}


def triangle_stiffness(P: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """Spring stiffness ``(T, 6, 6)`` of triangles with vertices ``P`` ``(T, 3, 2)`` (complex-safe).

    Every term is an outer product, so ``K = M^T M`` with the rows of ``M`` ``(T, 6, 6)``
    ``sqrt(1 / (2 L^3)) [-d, d]`` on each edge's ends (``d`` the edge vector) and
    ``sqrt(TSC C_r) R_r``: one batched product instead of many small strided sums.
    """
    T = P.shape[0]
    M = np.zeros((T, 6, 6), dtype=P.dtype)
    d = P[:, [1, 2, 0]] - P[:, [0, 1, 2]]                       # edge e = (e, e + 1)
    L2 = np.einsum("tei,tei->te", d, d)
    lineal = np.sqrt(0.5 / L2**1.5)[..., None] * d
    for e, (p, q) in enumerate(((0, 1), (1, 2), (2, 0))):
        M[:, e, 2 * p:2 * p + 2] = -lineal[:, e]
        M[:, e, 2 * q:2 * q + 2] = lineal[:, e]
    if torsion_scale != 0.0:
        x, y = P[..., 0], P[..., 1]
        area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
        C = np.stack([L2[:, 0] * L2[:, 2], L2[:, 1] * L2[:, 0], L2[:, 2] * L2[:, 1]], axis=1) / (area2**2)[:, None]
        M[:, 3:] = np.sqrt(torsion_scale * C)[..., None] * angle_gradients(d, L2)
    return np.matmul(M.transpose(0, 2, 1), M)


def angle_gradients(d: np.ndarray, L2: np.ndarray) -> np.ndarray:
    """Rows ``R_r = grad theta_r`` ``(T, 3, 6)`` of a triangle's angles from its edge vectors
    ``d`` ``(T, 3, 2)`` (edge ``e = (e, e + 1)``) and their squared lengths ``L2``: the edge is
    ``d_ij`` of the angle at its first end (``-phi(d)``) and ``d_ik`` reversed of the angle at its
    second (``+phi(-d)``, whose gradient in ``d`` is ``grad phi(d) = (-d_y, d_x) / L^2``)."""
    grad = np.stack([-d[..., 1], d[..., 0]], axis=-1) / L2[..., None]
    R = np.zeros(d.shape[:1] + (3, 6), dtype=d.dtype)
    for e, (p, q) in enumerate(((0, 1), (1, 2), (2, 0))):
        ip, iq = slice(2 * p, 2 * p + 2), slice(2 * q, 2 * q + 2)
        R[:, p, iq] -= grad[:, e]
        R[:, p, ip] += grad[:, e]
        R[:, q, iq] += grad[:, e]
        R[:, q, ip] -= grad[:, e]
    return R


def triangle_force_derivative(P: np.ndarray, v: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """``d(K(P) v)/dP`` ``(T, 6, 6)`` of triangles ``P`` ``(T, 3, 2)`` for vertex motions ``v``
    ``(T, 6)`` held fixed (real ``P``; module docstring). Each edge ``e = (p, q)``, ``q = p + 1``
    cyclically, is a side of the angles at ``p`` (as ``d_ij``, sign -) and at ``q`` (as ``d_ik``,
    sign +), and ``hess phi`` is even, so ``sum_r c_r H_r`` is a sum over the three edges of
    ``(c_q - c_p)`` times ``hess phi(d_e)`` placed as ``[[h, -h], [-h, h]]`` on ``(p, q)``."""
    T = P.shape[0]
    D = np.zeros((T, 6, 6))
    edges = ((0, 1), (1, 2), (2, 0))
    slots = [(slice(2 * p, 2 * p + 2), slice(2 * q, 2 * q + 2)) for p, q in edges]
    d = np.stack([P[:, q] - P[:, p] for p, q in edges], axis=1)                 # (T, 3, 2)
    L2 = np.einsum("tei,tei->te", d, d)
    for e, (ip, iq) in enumerate(slots):
        delta = v[:, iq] - v[:, ip]
        dd = np.einsum("ti,ti->t", d[:, e], delta)
        G = (np.einsum("ti,tj->tij", d[:, e], delta) + dd[:, None, None] * np.eye(2)
             - 3 * (dd / L2[:, e])[:, None, None] * np.einsum("ti,tj->tij", d[:, e], d[:, e]))
        G /= (2 * L2[:, e] ** 1.5)[:, None, None]
        D[:, iq, iq] += G
        D[:, ip, ip] += G
        D[:, iq, ip] -= G
        D[:, ip, iq] -= G
    if torsion_scale == 0.0:
        return D
    dx, dy = d[..., 0], d[..., 1]
    off = dy**2 - dx**2
    h = np.stack([np.stack([2 * dx * dy, off], -1), np.stack([off, -2 * dx * dy], -1)], -2) / (L2**2)[..., None, None]
    x, y = P[..., 0], P[..., 1]
    area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    grad_area2 = np.stack([y[:, 1] - y[:, 2], x[:, 2] - x[:, 1], y[:, 2] - y[:, 0], x[:, 0] - x[:, 2],
                           y[:, 0] - y[:, 1], x[:, 1] - x[:, 0]], axis=1) / area2[:, None]
    R = angle_gradients(d, L2)               # row r: grad theta_r
    Hv = np.zeros((T, 3, 6))                 # row r: H_r v
    dlogC = np.zeros((T, 3, 6))              # row r: grad C_r / C_r
    for e, ((p, q), (ip, iq)) in enumerate(zip(edges, slots, strict=True)):
        hu = np.einsum("tij,tj->ti", h[:, e], v[:, iq] - v[:, ip])             # [[h, -h], [-h, h]] v = (-hu, hu)
        for r, sign in ((p, -1.0), (q, 1.0)):        # e is d_ij of the angle at p, -d_ik of the angle at q
            Hv[:, r, iq] += sign * hu
            Hv[:, r, ip] -= sign * hu
            dlogC[:, r, iq] += 2 * d[:, e] / L2[:, e, None]                          # grad L_e^2 / L_e^2
            dlogC[:, r, ip] -= 2 * d[:, e] / L2[:, e, None]
    C = np.stack([L2[:, 0] * L2[:, 2], L2[:, 1] * L2[:, 0], L2[:, 2] * L2[:, 1]], axis=1) / (area2**2)[:, None]
    dlogC -= 2 * grad_area2[:, None, :]
    w = np.einsum("tri,ti->tr", R, v)
    c = C * w
    for e, (ip, iq) in enumerate(slots):
        Ge = (c[:, edges[e][1]] - c[:, edges[e][0]])[:, None, None] * h[:, e]
        D[:, iq, iq] += torsion_scale * Ge
        D[:, ip, ip] += torsion_scale * Ge
        D[:, iq, ip] -= torsion_scale * Ge
        D[:, ip, iq] -= torsion_scale * Ge
    right = c[..., None] * dlogC + C[..., None] * Hv
    return D + torsion_scale * np.einsum("tri,trj->tij", R, right)


class TriangleSplit:
    """How quads with diagonal codes ``(E,)`` (0 = "1-3", 1 = "2-4", 2 = "both") split into
    triangles, built once per set of codes: per triangle its corners' rows of ``Xe.reshape(-1, 2)``
    ``(T, 3)``, its dofs' entries of ``v.reshape(-1)`` ``(T, 6)``, and the sparse map (weight 1,
    or 1/2 for both diagonals) from the triangles' ``(T, 6, 6)`` to the quads' ``(E, 8, 8)``."""

    def __init__(self, diagonal: np.ndarray):
        diagonal = np.asarray(diagonal)
        self.n_quads = diagonal.size
        quads, corners, weights = [], [], []
        for code, name in enumerate(("1-3", "2-4")):
            weight = np.where(diagonal == code, 1.0, np.where(diagonal == 2, 0.5, 0.0))
            q = np.flatnonzero(weight > 0)
            for tri in TRIANGLES[name]:
                quads.append(q)
                corners.append(np.broadcast_to(np.array(tri), (q.size, 3)))
                weights.append(weight[q])
        quad, corner, weight = np.concatenate(quads), np.concatenate(corners), np.concatenate(weights)
        local = np.stack([2 * corner, 2 * corner + 1], axis=-1).reshape(-1, 6)     # the quad's dofs
        self.corners = 4 * quad[:, None] + corner
        self.dofs = 8 * quad[:, None] + local
        rows = (64 * quad[:, None, None] + 8 * local[:, :, None] + local[:, None, :]).ravel()
        self.scatter = sp.csr_matrix((np.repeat(weight, 36), (rows, np.arange(rows.size))),
                                     shape=(64 * self.n_quads, rows.size))


def _on_triangles(Xe: np.ndarray, split: "TriangleSplit", triangle_fn, v: np.ndarray | None = None) -> np.ndarray:
    """``(E, 8, 8)``: per quad the weighted sum of ``triangle_fn`` over its triangles (one call for
    all of them), each placed at its triangle's quad dofs. ``triangle_fn(P (T, 3, 2), v (T, 6))``;
    ``v`` ``(E, 8)`` per quad, or None."""
    P = np.asarray(Xe).reshape(-1, 2)[split.corners]
    vt = None if v is None else np.asarray(v).reshape(-1)[split.dofs]
    return (split.scatter @ triangle_fn(P, vt).reshape(-1)).reshape(split.n_quads, 8, 8)


def _split(diagonal) -> TriangleSplit:
    return diagonal if isinstance(diagonal, TriangleSplit) else TriangleSplit(diagonal)


def quad_stiffness(Xe: np.ndarray, diagonal: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """Spring stiffness ``(E, 8, 8)`` of quads ``Xe`` ``(E, 4, 2)`` (complex-safe).

    diagonal : (E,) codes 0 = "1-3", 1 = "2-4", 2 = "both", or their :class:`TriangleSplit`
    """
    return _on_triangles(Xe, _split(diagonal), lambda P, _: triangle_stiffness(P, torsion_scale))


def quad_force_derivative(Xe: np.ndarray, v: np.ndarray, diagonal: np.ndarray,
                          torsion_scale: float = 1.0) -> np.ndarray:
    """``d(quad_stiffness(Xe) v)/dXe`` ``(E, 8, 8)`` (last axis the corner coordinate ``2 a + i``)
    for quad motions ``v`` ``(E, 8)`` held fixed; ``diagonal`` as :func:`quad_stiffness`."""
    return _on_triangles(Xe, _split(diagonal), lambda P, vt: triangle_force_derivative(P, vt, torsion_scale), v)
