"""Derivatives by the complex step, for batched element functions.

For a function ``f`` that accepts complex input and is real-analytic in it,

    df/dx = Im f(x + i h) / h + O(h^2),    h = 1e-30,

exact to round-off: there is no subtraction, so no cancellation. For the
shape derivative of an element function of the corners ``Xe`` ``(E, 4, 2)``
that costs one complex evaluation per corner coordinate, eight in all.
"""

from __future__ import annotations

import numpy as np

COMPLEX_STEP = 1e-30


def corner_derivatives(fn, Xe: np.ndarray) -> np.ndarray:
    """``d fn(Xe) / d Xe`` ``(E, ..., 8)``; the last axis is the corner coordinate ``2 a + i``.

    fn : ``Xe (E, 4, 2) -> (E, ...)``, complex-safe.
    """
    columns = []
    for j in range(8):
        Xc = Xe.astype(complex)
        Xc[:, j // 2, j % 2] += 1j * COMPLEX_STEP
        columns.append(np.asarray(fn(Xc)).imag / COMPLEX_STEP)
    return np.stack(columns, axis=-1)


def derivative(fn, x):
    """``d fn(x) / dx`` for a scalar (or elementwise) parameter ``x``, complex-safe ``fn``."""
    return np.asarray(fn(np.asarray(x) + 1j * COMPLEX_STEP)).imag / COMPLEX_STEP
