"""The optimality-criteria update of topFlow (Alexandersen 2023) and top88, for one volume bound.

With ``y`` the bounded phase (the solid ``gamma``, or the fluid ``1 - gamma`` under a fluid
bound), ``dV_e`` its volume weights and ``df/dy`` the objective's gradient, one step is

    y_new = clip(y (B / lambda)^eta,  max(0, y - m),  min(1, y + m)),
    B = max(1e-10, -(df/dy) / dV),

with the multiplier ``lambda`` found by bisection so that the phase fraction meets the bound
(``eta = 1/3`` and move limit ``m = 0.2`` as topFlow; bisection from topFlow's bracket
``[0, (sum y B^eta / (n V))^(1/eta)]`` to a relative width of 1e-3). At a fixed point every
element strictly inside its bounds has ``B = lambda``: the KKT condition of the problem.
The phase fraction may be any monotone function of ``y`` (a filter and a projection
included); it is evaluated without a solve. The returned design meets the bound to the
bisection's tolerance (topFlow's last midpoint), or, when no design within the move limit
meets it, is the one nearest to it.
"""

from __future__ import annotations

import numpy as np

MOVE = 0.2
EXPONENT = 1.0 / 3.0
TOLERANCE = 1e-3
FLOOR = 1e-10


def oc_step(gamma: np.ndarray, df: np.ndarray, dvolume: np.ndarray, fraction, bound: float,
            solid_bound: bool = True, move: float = MOVE, exponent: float = EXPONENT) -> np.ndarray:
    """The next design ``gamma`` (n,) of one OC step.

    df : objective gradient d f / d gamma (n,); dvolume : d (phase fraction) / d y (n,), positive
    fraction : ``gamma -> phase fraction`` (no solve); bound : the largest fraction allowed
    solid_bound : the bound limits the solid (True) or the fluid ``1 - gamma`` (False)
    """
    gamma = np.asarray(gamma, dtype=float)
    sign = 1.0 if solid_bound else -1.0
    y = gamma if solid_bound else 1.0 - gamma
    B = np.maximum(FLOOR, -sign * np.asarray(df) / np.asarray(dvolume))
    factor = y * B**exponent
    low, high = np.maximum(0.0, y - move), np.minimum(1.0, y + move)

    def design(lam):
        y_new = np.clip(factor / lam**exponent, low, high)
        return y_new if solid_bound else 1.0 - y_new

    if fraction(design(np.inf)) > bound:             # out of reach within the move limit:
        return design(np.inf)                        # the nearest design, every y at its lower end
    l1, l2 = 0.0, (factor.sum() / (y.size * bound)) ** (1.0 / exponent)
    # widen topFlow's bracket where it is short (the design at its end breaks the bound); where
    # no design variable is clipped that design meets the bound exactly, so round-off in the
    # fraction decides nothing
    while fraction(design(l2)) > bound * (1.0 + 1e-9):
        l1, l2 = l2, 2.0 * l2
    new = design(l2)
    while (l2 - l1) / (l1 + l2) > TOLERANCE:        # the last midpoint's design, as topFlow
        mid = 0.5 * (l1 + l2)
        new = design(mid)
        l1, l2 = (mid, l2) if fraction(new) > bound else (l1, mid)
    return new
