"""Lagrange shape functions on the reference square, corners counter-clockwise.

Q1 (4 nodes): corners (-1,-1), (1,-1), (1,1), (-1,1).
Q2 (9 nodes): the 4 corners, then the mid-sides bottom, right, top, left,
then the centre -- the ordering of :attr:`tofsi.mesh.StructuredQuadMesh.quads9`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

Q1_NODES = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
Q2_NODES = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1],
                     [0, -1], [1, 0], [0, 1], [-1, 0], [0, 0]], dtype=float)


def _lagrange_1d(nodes: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values and derivatives ``(len(s), len(nodes))`` of 1D Lagrange polynomials."""
    s = np.asarray(s, dtype=float)[:, None]
    k = len(nodes)
    values = np.ones((s.shape[0], k))
    derivs = np.zeros((s.shape[0], k))
    for a in range(k):
        others = [b for b in range(k) if b != a]
        denom = np.prod([nodes[a] - nodes[b] for b in others])
        values[:, a] = np.prod([s[:, 0] - nodes[b] for b in others], axis=0) / denom
        for c in others:
            rest = [b for b in others if b != c]
            derivs[:, a] += np.prod([s[:, 0] - nodes[b] for b in rest], axis=0) / denom
    return values, derivs


@lru_cache(maxsize=None)
def _tables(degree: int, points_key: bytes, n_points: int):
    points = np.frombuffer(points_key).reshape(n_points, 2)
    nodes_1d = np.linspace(-1.0, 1.0, degree + 1)
    ref = Q1_NODES if degree == 1 else Q2_NODES
    index = np.rint((ref + 1.0) * degree / 2.0).astype(int)   # 1D node index per direction
    vx, dx = _lagrange_1d(nodes_1d, points[:, 0])
    vy, dy = _lagrange_1d(nodes_1d, points[:, 1])
    N = vx[:, index[:, 0]] * vy[:, index[:, 1]]                       # (G, k)
    dN = np.stack([dx[:, index[:, 0]] * vy[:, index[:, 1]],
                   vx[:, index[:, 0]] * dy[:, index[:, 1]]], axis=-1)  # (G, k, 2)
    N.setflags(write=False)
    dN.setflags(write=False)
    return N, dN


def shape_functions(degree: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values ``(G, k)`` and reference gradients ``(G, k, 2)`` at ``points`` ``(G, 2)``."""
    points = np.ascontiguousarray(points, dtype=float)
    return _tables(degree, points.tobytes(), points.shape[0])
