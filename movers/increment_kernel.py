"""What one increment of a move in increments is made of: the element matrices of the current
mesh with their shape derivative (:class:`IncrementKernel`), the increments' shares of the
motion and where each takes its stiffness (:func:`schedule`, :func:`stiffness_points`).

Shared by the serial moves in increments (:mod:`movers.incremental`) and the moves by slabs
(:mod:`tofsi.parallel.slab_increments`).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from tofsi.fem.complex_step import corner_derivatives

ElementMatrices = Callable[[np.ndarray], np.ndarray]


class IncrementKernel:
    """A mover's element matrices of the current mesh, ``Xe (Em, 4, 2) -> K0 (Em, 8, 8)``
    (unscaled, complex-safe), and the shape derivative of their forces
    ``d(K0(Xe) v_e)/dXe (Em, 8, 8)``: ``force_derivative`` where the mover gives it in closed
    form, else by complex step (eight evaluations of the matrices).

    ``extrapolation`` ``a``: where increment ``k >= 1`` takes its stiffness,
    ``y_k = x_k + a (h_k / h_(k-1)) (x_k - x_(k-1))`` (:func:`schedule`, ``h_k`` the increments'
    shares of the motion): 0, the start of the increment (forward Euler in the load, the
    paper's); 1/2, its midpoint extrapolated from the increment before (second order in the
    increment size at the same one solve per increment). ``first``: the first increment's share
    of the motion, the others equal (0: all equal). With ``a = 1/2`` the first increment alone
    takes its stiffness at its start (nothing before it to extrapolate from), so its error is
    first order: a small first increment (the large scene's 0.1 of 3) keeps the whole path
    second order. ``key``: the matrices' inputs besides the corners
    (:func:`~tofsi.core.kept.input_key`), or None; with it the first increment's matrices and
    system are kept (:func:`movers.incremental.stiffness_and_system`)."""

    def __init__(self, matrices: ElementMatrices, force_derivative=None, extrapolation: float = 0.0,
                 key: tuple | None = None, first: float = 0.0):
        self.matrices, self.closed_form = matrices, force_derivative
        self.extrapolation = float(extrapolation)
        self.first = float(first)
        self.key = key

    def __call__(self, Xe: np.ndarray) -> np.ndarray:
        return self.matrices(Xe)

    def force_derivative(self, Xe: np.ndarray, v: np.ndarray) -> np.ndarray:
        if self.closed_form is not None:
            return self.closed_form(Xe, v)
        return corner_derivatives(lambda Xc: np.einsum("eab,eb->ea", self.matrices(Xc), v), Xe)


def schedule(kernel: IncrementKernel, n: int) -> tuple[np.ndarray, list[float]]:
    """The ``n`` increments' shares ``h_k`` of the motion (summing to 1; the first
    :class:`IncrementKernel`'s ``first`` where it is set and ``n > 1``, the others equal) and their
    extrapolations ``a_k`` (``a_0 = 0``, ``a_k = a h_k / h_(k-1)``, ``a`` the kernel's
    ``extrapolation``): increment ``k`` moves by ``h_k`` times the target with the stiffness at
    ``y_k = x_k + a_k (x_k - x_(k-1))``, the midpoint of the increment (``a = 1/2``) extrapolated
    from the increment before, whatever their sizes."""
    first, a = kernel.first, kernel.extrapolation
    if first and n > 1:
        fractions = np.full(n, (1.0 - first) / (n - 1))
        fractions[0] = first
    else:
        fractions = np.full(n, 1.0 / n)
    return fractions, [a * fractions[k] / fractions[k - 1] if a and k else 0.0 for k in range(n)]


def stiffness_points(states: list[np.ndarray], extrapolations: list[float]) -> list[np.ndarray]:
    """Where each increment took its stiffness: ``y_k = x_k + a_k (x_k - x_(k-1))`` (``a_k`` the
    ``extrapolations`` of :func:`schedule`, ``a_0 = 0``), from ``states`` ``[x_0, ..., x_N]``."""
    return [states[k] + extrapolations[k] * (states[k] - states[k - 1]) if extrapolations[k] else states[k]
            for k in range(len(states) - 1)]
