"""Nested-dissection ordering of unknowns on a structured grid.

On a structured grid every unknown has integer grid coordinates (Q1 node
``(i, j)`` sits at fine-grid position ``(2i, 2j)``, Q2 nodes on the fine grid
itself). Recursively cutting the grid along its longer side and numbering
the cut last (nested dissection) gives SuperLU far less fill than its
built-in column orderings: on plane-strain elasticity with 1.6e5 unknowns
the factorization is about 3x faster than ``MMD_AT_PLUS_A`` (see
``benchmarks/README.md``).
"""

from __future__ import annotations

import numpy as np


LEAF = 4   # blocks of at most 4 grid positions: against 32, the large scene's coupled fields' LUs have
           # 7-13 % fewer entries and factorize 8 % and solve 12-18 % faster (80 x 40 and 160 x 80), the
           # one-way 180 x 90 design iteration 0-9 % less CPU and 4 % less peak (benchmarks/README.md)


def nested_dissection(coords: np.ndarray, leaf: int = LEAF, last=None) -> np.ndarray:
    """Permutation of unknowns with integer fine-grid positions ``coords`` ``(m, 2)``.

    Element corners sit on even fine-grid lines (Q2 mid-nodes on odd ones),
    so every cut is an even line: it separates the elements on its two sides.
    Each block of grid positions is cut at the middle of its longer side; the
    two halves are numbered first, the cut (separator) last. Unknowns at the
    same position (the components of a node, a velocity and a pressure) stay
    together; blocks of at most ``leaf`` positions are numbered as they come.

    last : optional boolean per unknown; within every block these come after
    the others. For saddle-point systems (pressures last) every pressure is
    eliminated after the velocities it couples to in its block, so its pivot is
    a non-zero Schur complement and the LU can keep the diagonal pivots.
    """
    coords = np.asarray(coords, dtype=np.int64)
    key = coords[:, 0] * (coords[:, 1].max() + 1) + coords[:, 1]
    unique_key, where = np.unique(key, return_inverse=True)
    P = coords[_first_index(where, unique_key.size)]              # one row per position
    order: list[np.ndarray] = []
    stack: list[tuple[bool, np.ndarray]] = [(False, np.arange(P.shape[0]))]
    while stack:                                   # post-order with an explicit stack
        emit, idx = stack.pop()
        if emit or idx.size <= leaf:
            order.append(idx)
            continue
        c = P[idx]
        lo, hi = c.min(axis=0), c.max(axis=0)
        axis = int(np.argmax(hi - lo))
        lo, hi = lo[axis], hi[axis]
        mid = 2 * ((lo + hi) // 4)                 # an even line near the middle
        on_line = c[:, axis] == mid
        if not (lo < mid < hi) or not on_line.any():
            lines = np.unique(c[:, axis])
            lines = lines[(lines % 2 == 0) & (lines > lo) & (lines < hi)]
            if lines.size == 0:
                order.append(idx)
                continue
            mid = lines[lines.size // 2]
            on_line = c[:, axis] == mid
        stack.append((True, idx[on_line]))
        stack.append((False, idx[c[:, axis] > mid]))
        stack.append((False, idx[c[:, axis] < mid]))
    rank = np.empty(P.shape[0], dtype=np.int64)
    rank[np.concatenate(order)] = np.arange(P.shape[0])
    if last is None:
        return np.argsort(rank[where], kind="stable")
    block = np.empty(P.shape[0], dtype=np.int64)
    block[np.concatenate(order)] = np.repeat(np.arange(len(order)), [len(o) for o in order])
    return np.lexsort((rank[where], np.asarray(last, dtype=np.int64), block[where]))


def _first_index(where: np.ndarray, n: int) -> np.ndarray:
    """Index of the first occurrence of each group ``0 .. n-1`` in ``where``."""
    first = np.full(n, where.size, dtype=np.int64)
    np.minimum.at(first, where, np.arange(where.size))
    return first
