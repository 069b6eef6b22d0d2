"""Lagrange shape functions on the reference square, corners counter-clockwise.

Q1 (4 nodes): corners (-1,-1), (1,-1), (1,1), (-1,1).
Q2 (9 nodes): the 4 corners, then the mid-sides bottom, right, top, left,
then the centre -- the ordering of :attr:`tofsi.mesh.structured.StructuredQuadMesh.quads9`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

Q1_NODES = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
Q2_NODES = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1],
                     [0, -1], [1, 0], [0, 1], [-1, 0], [0, 0]], dtype=float)


def _lagrange_1d(nodes: np.ndarray, s: np.ndarray):
    """Values, first and second derivatives ``(len(s), len(nodes))`` of 1D Lagrange polynomials."""
    P = np.polynomial.polynomial
    s = np.asarray(s, dtype=float)
    out = np.empty((3, s.size, len(nodes)))
    for a, node in enumerate(nodes):
        others = np.delete(nodes, a)
        c = P.polyfromroots(others) / np.prod(node - others)
        for order in range(3):
            out[order, :, a] = P.polyval(s, P.polyder(c, order))
    return out


@lru_cache(maxsize=None)
def _tables(degree: int, points_key: bytes, n_points: int):
    points = np.frombuffer(points_key).reshape(n_points, 2)
    nodes_1d = np.linspace(-1.0, 1.0, degree + 1)
    ref = Q1_NODES if degree == 1 else Q2_NODES
    ix, iy = (np.rint((ref + 1.0) * degree / 2.0).astype(int)).T   # 1D node index per direction
    X = _lagrange_1d(nodes_1d, points[:, 0])[:, :, ix]                # (3, G, k)
    Y = _lagrange_1d(nodes_1d, points[:, 1])[:, :, iy]
    N = X[0] * Y[0]                                                    # (G, k)
    dN = np.stack([X[1] * Y[0], X[0] * Y[1]], axis=-1)                 # (G, k, 2)
    d2N = np.stack([np.stack([X[2] * Y[0], X[1] * Y[1]], -1),
                    np.stack([X[1] * Y[1], X[0] * Y[2]], -1)], -2)     # (G, k, 2, 2)
    for a in (N, dN, d2N):
        a.setflags(write=False)
    return N, dN, d2N


def shape_functions(degree: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values ``(G, k)`` and reference gradients ``(G, k, 2)`` at ``points`` ``(G, 2)``."""
    points = np.ascontiguousarray(points, dtype=float)
    return _tables(degree, points.tobytes(), points.shape[0])[:2]


def shape_hessians(degree: int, points: np.ndarray) -> np.ndarray:
    """Reference second derivatives ``(G, k, 2, 2)`` at ``points`` ``(G, 2)``."""
    points = np.ascontiguousarray(points, dtype=float)
    return _tables(degree, points.tobytes(), points.shape[0])[2]
