"""Pieces every nonlinear iteration of the toolkit shares: the Newton forcing term,
a backtracking line search and the interface quasi-Newton update of a fixed point.

Each depends only on what it is given (the quasi-Newton update on the iterates so far), so
an iteration that uses them is reproducible bit for bit.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from tofsi.core.errors import NumericalError


def forcing_term(history: list[float], target: float) -> float:
    """Relative tolerance of the next inexact Newton solve (Eisenstat-Walker, choice 2).

    ``eta = 0.9 (r_k / r_(k-1))^2`` (0.1 at first), at most 0.1, and never tighter
    than the final tolerance needs: ``eta >= 0.1 target / r_k``.
    """
    eta = 0.1 if len(history) < 2 else min(0.1, 0.9 * (history[-1] / history[-2]) ** 2)
    return max(eta, 0.1 * target / history[-1])


def backtracking(merit0: float, trial: Callable[[float], tuple[float, object]],
                 halvings: int = 8, decrease: float = 1e-4):
    """Step length ``alpha = 1, 1/2, 1/4, ...`` with a sufficient decrease of a merit.

    trial : ``alpha -> (merit, payload)``; a trial that raises
        :class:`~tofsi.core.errors.NumericalError` (an inverted element, a failed
        sub-solve) or gives a non-finite merit is rejected.
    Accepts the first ``alpha`` with ``merit < (1 - decrease alpha) merit0`` and
    returns ``(alpha, payload)``, or None when every trial fails.
    """
    for alpha in 0.5 ** np.arange(halvings):
        try:
            merit, payload = trial(float(alpha))
        except NumericalError:
            continue
        if np.isfinite(merit) and merit < (1.0 - decrease * alpha) * merit0:
            return float(alpha), payload
    return None


class InterfaceQuasiNewton:
    """IQN-ILS, the interface quasi-Newton method with a least-squares Jacobian model (Degroote,
    Bathe & Vierendeels 2009), for a fixed point ``x = H(x)`` (a partitioned sweep).

    From the iterates' values ``h_k = H(x_k)`` and residuals ``r_k = h_k - x_k`` it keeps the
    differences ``V = [r_(i+1) - r_i]`` and ``W = [h_(i+1) - h_i]`` (the last ``columns``), solves
    ``min |V c + r_k|`` and takes ``x_(k+1) = h_k + W c``: a multi-secant model of the inverse of
    ``I - H'`` on the differences seen so far, exact on them, which removes the modes a relaxed
    fixed-point iteration amplifies (a sweep that diverges on one mode, as a soft structure whose
    mesh follows it does, converges). The first step is relaxed by ``omega``. Columns that the
    least squares cannot tell apart (singular values below ``rcond`` of the largest) are dropped.
    """

    def __init__(self, omega: float, columns: int = 30, rcond: float = 1e-10):
        self.omega, self.columns, self.rcond = omega, columns, rcond
        self.h, self.r = None, None
        self.V, self.W = [], []

    def next(self, x: np.ndarray, h: np.ndarray) -> np.ndarray:
        """The next iterate from the current one ``x`` and its value ``h = H(x)``."""
        r = h - x
        if self.h is not None:
            self.V.append(r - self.r)
            self.W.append(h - self.h)
            del self.V[:-self.columns], self.W[:-self.columns]
        self.h, self.r = h, r
        if not self.V:
            return x + self.omega * r
        c = np.linalg.lstsq(np.column_stack(self.V), -r, rcond=self.rcond)[0]
        return h + np.column_stack(self.W) @ c
