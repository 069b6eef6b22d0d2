"""What a failed move says: the element a trial step inverts (by the mesh's numbering), or that
none did; the quads whose element matrices are not finite at an increment's stiffness point;
locations rounded for messages."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofsi.core.errors import NumericalError
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


def non_finite_matrices(bad: np.ndarray, where: str = "") -> NumericalError:
    """The error of an increment whose element matrices are not finite on the quads ``bad`` (mesh
    numbering): inverted or degenerate at its stiffness point (``det J`` under a fractional
    power); ``where`` is added to the message (serial moves and moves by slabs say the same)."""
    bad = np.sort(np.asarray(bad))
    return NumericalError(f"the element matrices of {bad.size} quad(s) are not finite at the increment's "
                          f"stiffness point (elements {', '.join(map(str, bad[:5]))}{', ...' if bad.size > 5 else ''}: "
                          f"inverted or degenerate there){where}", {"non_finite_elements": bad.tolist()})


def require_finite_matrices(problem, K0: np.ndarray, index: int, report) -> None:
    """Raise :func:`non_finite_matrices` where increment ``index``'s element matrices ``K0``
    (Em, 8, 8) of the :class:`~movers.problem.MotionProblem` ``problem`` are not finite, with where
    the previous increment left the mesh (the move's :class:`~movers.base.MoveReport` ``report``),
    before any solve sees them."""
    finite = np.isfinite(K0).all(axis=(1, 2))
    if finite.all():
        return
    after = ""
    if report.quality:
        q = report.quality[-1]
        after = (f"; after increment {index} the worst element is {q['worst_element']} (skewness "
                 f"{q['min_skewness']:.3g}, {q['n_inverted']} inverted) at {at(q['worst_location'])}")
    raise non_finite_matrices(problem.element_ids[~finite], f" at increment {index + 1}{after}")
