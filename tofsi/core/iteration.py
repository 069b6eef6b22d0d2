"""Pieces every nonlinear iteration of the toolkit shares: the Newton forcing term,
a backtracking line search and Aitken's relaxation.

Each is a pure function of its arguments, so an iteration that uses them is
reproducible bit for bit.
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


def aitken(omega: float, r: np.ndarray, r_previous: np.ndarray | None) -> float:
    """Aitken's dynamic relaxation factor for a fixed-point iteration with residuals ``r``.

    ``omega_k = -omega_(k-1) r_(k-1) . (r_k - r_(k-1)) / |r_k - r_(k-1)|^2``;
    the first factor is kept while there is no previous residual.
    """
    if r_previous is None:
        return omega
    dr = r - r_previous
    return -omega * float(r_previous @ dr) / max(float(dr @ dr), 1e-300)
