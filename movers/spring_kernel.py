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


EDGES = ((0, 1), (1, 2), (2, 0))          # edge e runs from vertex e to vertex e + 1 (cyclically)
FIRST, SECOND = [0, 1, 2], [1, 2, 0]      # their first and second ends

_ENDS = np.zeros((3, 6, 2))                # B_e: an edge's 2-vector g -> (-g on its first end, +g on its second)
for _e, (_p, _q) in enumerate(EDGES):
    _ENDS[_e, 2 * _p:2 * _p + 2] = -np.eye(2)
    _ENDS[_e, 2 * _q:2 * _q + 2] = np.eye(2)
_SIGN = np.array([[-1.0, 0.0, 1.0], [1.0, -1.0, 0.0], [0.0, 1.0, -1.0]])   # [r, e]: -1 / +1 at e's first / second end


def _rows(S: np.ndarray) -> np.ndarray:
    """``(6, 18)``: per-edge 2-vectors ``g`` ``(T, 3, 2)`` flattened ``-> (T, 3, 6)`` flattened,
    row ``r`` ``sum_e S[r, e] B_e g_e`` (one matrix product for all triangles)."""
    return np.einsum("re,eai->eira", S, _ENDS).reshape(6, 18)


_EDGE_ROWS, _SIGNED_ROWS, _END_ROWS = _rows(np.eye(3)), _rows(_SIGN), _rows(np.abs(_SIGN))
_PLACE = np.einsum("eai,ebj->eijab", _ENDS, _ENDS).reshape(12, 36)     # sum_e B_e G_e B_e^T, (T, 12) -> (T, 36)


def _on_rows(g: np.ndarray, rows: np.ndarray) -> np.ndarray:
    return (g.reshape(len(g), 6) @ rows).reshape(len(g), 3, 6)


def triangle_stiffness(P: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """Spring stiffness ``(T, 6, 6)`` of triangles with vertices ``P`` ``(T, 3, 2)`` (complex-safe).

    Every term is an outer product, so ``K = M^T M`` with the rows of ``M`` ``(T, 6, 6)``
    ``sqrt(1 / (2 L^3)) [-d, d]`` on each edge's ends (``d`` the edge vector) and
    ``sqrt(TSC C_r) R_r``: one batched product instead of many small strided sums.
    """
    T = P.shape[0]
    d = P[:, SECOND] - P[:, FIRST]
    L2 = np.einsum("tei,tei->te", d, d)
    lineal = _on_rows(np.sqrt(0.5 / L2**1.5)[..., None] * d, _EDGE_ROWS)
    if torsion_scale == 0.0:
        M = lineal
    else:
        x, y = P[..., 0], P[..., 1]
        area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
        C = L2[:, FIRST] * L2[:, [2, 0, 1]] / (area2**2)[:, None]
        M = np.concatenate([lineal, np.sqrt(torsion_scale * C)[..., None] * angle_gradients(d, L2)], axis=1)
    return np.matmul(M.transpose(0, 2, 1), M).reshape(T, 6, 6)


def angle_gradients(d: np.ndarray, L2: np.ndarray) -> np.ndarray:
    """Rows ``R_r = grad theta_r`` ``(T, 3, 6)`` of a triangle's angles from its edge vectors
    ``d`` ``(T, 3, 2)`` (edge ``e = (e, e + 1)``) and their squared lengths ``L2``: the edge is
    ``d_ij`` of the angle at its first end (``-phi(d)``) and ``d_ik`` reversed of the angle at its
    second (``+phi(-d)``, whose gradient in ``d`` is ``grad phi(d) = (-d_y, d_x) / L^2``)."""
    grad = np.stack([-d[..., 1], d[..., 0]], axis=-1) / L2[..., None]
    return _on_rows(grad, _SIGNED_ROWS)


def triangle_force_derivative(P: np.ndarray, v: np.ndarray, torsion_scale: float = 1.0) -> np.ndarray:
    """``d(K(P) v)/dP`` ``(T, 6, 6)`` of triangles ``P`` ``(T, 3, 2)`` for vertex motions ``v``
    ``(T, 6)`` held fixed (real ``P``; module docstring). Each edge ``e = (p, q)``, ``q = p + 1``
    cyclically, is a side of the angles at ``p`` (as ``d_ij``, sign -) and at ``q`` (as ``d_ik``,
    sign +), and ``hess phi`` is even, so ``sum_r c_r H_r`` is a sum over the three edges of
    ``(c_q - c_p)`` times ``hess phi(d_e)`` placed as ``[[h, -h], [-h, h]]`` on ``(p, q)``: with the
    lineal ``dg/dd`` one 2 x 2 block per edge, placed on its ends by one matrix product."""
    T = P.shape[0]
    d = P[:, SECOND] - P[:, FIRST]                                   # (T, 3, 2)
    vp = v.reshape(T, 3, 2)
    delta = vp[:, SECOND] - vp[:, FIRST]
    L2 = np.einsum("tei,tei->te", d, d)
    dd = np.einsum("tei,tei->te", d, delta)
    G = d[..., :, None] * delta[..., None, :] - (3 * dd / L2)[..., None, None] * (d[..., :, None] * d[..., None, :])
    G[..., 0, 0] += dd
    G[..., 1, 1] += dd
    G /= (2 * L2**1.5)[..., None, None]                              # lineal dg/dd per edge
    if torsion_scale == 0.0:
        return (G.reshape(T, 12) @ _PLACE).reshape(T, 6, 6)
    dx, dy = d[..., 0], d[..., 1]
    L4 = L2**2
    h = np.empty((T, 3, 2, 2))                                       # hess phi(d_e)
    h[..., 0, 0] = 2 * dx * dy / L4
    h[..., 1, 1] = -h[..., 0, 0]
    h[..., 0, 1] = h[..., 1, 0] = (dy**2 - dx**2) / L4
    x, y = P[..., 0], P[..., 1]
    area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    grad_area2 = np.stack([y[:, 1] - y[:, 2], x[:, 2] - x[:, 1], y[:, 2] - y[:, 0], x[:, 0] - x[:, 2],
                           y[:, 0] - y[:, 1], x[:, 1] - x[:, 0]], axis=1) / area2[:, None]
    R = angle_gradients(d, L2)                                       # row r: grad theta_r
    Hv = _on_rows(np.einsum("teij,tej->tei", h, delta), _SIGNED_ROWS)   # row r: H_r v
    dlogC = _on_rows(2 * d / L2[..., None], _END_ROWS) - 2 * grad_area2[:, None, :]   # row r: grad C_r / C_r
    C = L2[:, FIRST] * L2[:, [2, 0, 1]] / (area2**2)[:, None]
    c = C * np.einsum("tri,ti->tr", R, v)                            # C_r w_r
    G += (torsion_scale * (c[:, SECOND] - c[:, FIRST]))[..., None, None] * h
    right = c[..., None] * dlogC + C[..., None] * Hv
    return (G.reshape(T, 12) @ _PLACE).reshape(T, 6, 6) + torsion_scale * np.matmul(R.transpose(0, 2, 1), right)


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
