"""Gradient checks: the Taylor test and central differences (pyadjoint's ``taylor_test`` idea).

For a scalar ``f`` with claimed gradient ``g`` at ``x`` and a direction ``d``,
the remainders ``r(eps) = |f(x + eps d) - f(x) - eps g . d|`` fall as
``eps^2`` when ``g`` is right and as ``eps`` when a term is missing; the
rates ``log2(r(eps) / r(eps/2))`` for ``eps = eps0 / 2^k`` show which.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass
class TaylorResult:
    eps: list
    remainders: list
    rates: list
    min_rate: float

    def as_dict(self) -> dict:
        return asdict(self)


def taylor_test(f, x: np.ndarray, gradient: np.ndarray, direction: np.ndarray,
                eps0: float = 1e-2, steps: int = 5, f0: float | None = None) -> TaylorResult:
    """Remainders and rates of the first-order Taylor expansion along ``direction``."""
    f0 = f(x) if f0 is None else f0
    slope = float(np.dot(gradient, direction))
    eps = [eps0 / 2**k for k in range(steps)]
    rem = [abs(f(x + e * direction) - f0 - e * slope) for e in eps]
    rates = [float(np.log2(rem[k] / rem[k + 1])) if rem[k + 1] > 0 else np.inf for k in range(steps - 1)]
    return TaylorResult(eps, rem, rates, float(min(rates)))


def central_difference(f, x: np.ndarray, direction: np.ndarray, h: float) -> float:
    """``(f(x + h d) - f(x - h d)) / 2h``."""
    return (f(x + h * direction) - f(x - h * direction)) / (2 * h)


def relative_error(a: float, b: float, floor: float = 1e-300) -> float:
    return abs(a - b) / max(abs(a), abs(b), floor)
