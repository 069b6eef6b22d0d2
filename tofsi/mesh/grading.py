"""Graded 1D grid lines that contain every geometric breakpoint.

The target element size grows linearly with the distance ``d`` to the
nearest feature interval (the extent of a structure along this axis)::

    h(s) = min(h_max, h_min + (growth - 1) d(s))

which is the continuous version of neighbouring elements growing by the
factor ``growth``. Each segment between consecutive breakpoints receives
``round(int 1/h ds)`` elements (at least one) placed so that every element
holds the same share of ``int 1/h ds`` (equidistribution). Grid lines
therefore hit every structure edge exactly.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np

from tofsi.core.errors import InputError


def distance_to_intervals(s: np.ndarray, intervals: list[tuple[float, float]]) -> np.ndarray:
    """Distance from each ``s`` to the union of closed ``intervals`` (0 inside)."""
    d = np.full_like(s, np.inf, dtype=float)
    for a, b in intervals:
        d = np.minimum(d, np.maximum.reduce([a - s, s - b, np.zeros_like(s)]))
    return d


def graded_axis(length: float, breakpoints, features, h_min: float, h_max: float,
                growth: float, samples: int = 2001) -> np.ndarray:
    """Sorted grid-line coordinates on ``[0, length]`` containing every breakpoint.

    ``features``: intervals where the size is ``h_min``; with none the size is
    ``h_max`` everywhere.
    """
    if not (0 < h_min <= h_max):
        raise InputError("mesh.h_min", h_min, f"allowed: 0 < h_min <= h_max = {h_max}")
    tol = 1e-12 * length
    cuts = np.unique(np.clip(np.r_[0.0, length, np.asarray(breakpoints, float)], 0.0, length))
    cuts = cuts[np.r_[True, np.diff(cuts) > tol]]
    cuts[-1] = length
    lines = [0.0]
    for a, b in pairwise(cuts):
        s = np.linspace(a, b, samples)
        if features:
            h = np.minimum(h_max, h_min + (growth - 1.0) * distance_to_intervals(s, features))
        else:
            h = np.full_like(s, h_max)
        inv = 1.0 / h
        cumulative = np.r_[0.0, np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(s))]
        m = max(1, int(round(cumulative[-1])))
        targets = cumulative[-1] * np.arange(1, m) / m
        lines.extend(np.interp(targets, cumulative, s))
        lines.append(b)
    return np.asarray(lines)
