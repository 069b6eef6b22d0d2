"""What a failed move says: the element a trial step inverts (by the mesh's numbering), or that
none did; locations rounded for messages."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofsi.mesh import quality


def at(location) -> str:
    """``(0.741, 0.454) m``: a location in a message, to 3 significant digits."""
    return f"({location[0]:.3g}, {location[1]:.3g}) m"


def broken_element(problem, x: np.ndarray, det_min: np.ndarray | None = None) -> dict | None:
    """The element a trial displacement ``x`` (2n,) breaks: the one with the smallest
    ``det F`` when some is <= 0 (``det_min`` (Em,), per element), else the most inverted by
    its corners; None when no element is inverted. Numbered by the mesh
    (``problem.element_ids`` of the :class:`~movers.problem.MotionProblem`), located at its
    reference centre."""
    P = problem.points + np.asarray(x).reshape(-1, 2)
    corners = quality.corner_jacobians(P, problem.quads).min(axis=1)          # (Em,)
    if det_min is not None and np.min(det_min) <= 0.0:
        k = int(np.argmin(det_min))
    elif np.min(corners) <= 0.0:
        k = int(np.argmin(corners))
    else:
        return None
    centre = problem.points[problem.quads[k]].mean(axis=0)
    return {"element": int(problem.element_ids[k]), "location": [float(centre[0]), float(centre[1])],
            "skewness": float(quality.skewness(P, problem.quads[k:k + 1])[0])}


def describe_break(broken: dict | None) -> str:
    """``inverts element 954 at (0.743, 0.454) m (skewness -0.26)``, or that none is inverted."""
    if broken is None:
        return "no element inverted"
    return (f"inverts element {broken['element']} at {at(broken['location'])} "
            f"(skewness {broken['skewness']:.2g})")


@dataclass(frozen=True)
class Trouble:
    """Why a step failed: ``text`` for the message, ``broken`` the element it inverted
    (:func:`broken_element`; None when the mesh stayed valid)."""

    text: str
    broken: dict | None = None

    def __str__(self) -> str:
        return self.text
