"""Tensor-product Gauss-Legendre rules on the reference square [-1, 1]^2."""

from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=None)
def gauss_square(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(G, 2)`` and weights ``(G,)`` of the ``order`` x ``order`` Gauss rule.

    An ``order``-point rule per direction integrates polynomials of degree
    ``2 order - 1`` in each variable exactly.
    """
    s, w = np.polynomial.legendre.leggauss(order)
    xi, eta = np.meshgrid(s, s, indexing="xy")
    points = np.column_stack([xi.ravel(), eta.ravel()])
    weights = np.outer(w, w).ravel()
    points.setflags(write=False)
    weights.setflags(write=False)
    return points, weights
