"""Mesh quality of quadrilaterals: skewness, area change, inversion.

Skewness of a corner with interior angle theta (degrees) is
``1 - max((theta - 90)/90, (90 - theta)/90) = 1 - |theta - 90| / 90``;
an element's skewness is the minimum over its four corners (1 for a
rectangle, 0 for a degenerate corner, negative for a reflex or inverted
corner). The angle is *signed*: with the edges leaving the corner,
``theta = atan2(cross(e_next, e_prev), dot(e_next, e_prev))`` mapped to
[0, 360), so a clockwise (inverted) corner gives theta > 180.

Area change is ``A / A0`` with signed (shoelace) areas, negative when an
element is mirrored.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

SKEWNESS_LABEL = "skewness (1 square corners, 0 degenerate, < 0 inverted)"
"""What the skewness scale means, for colour bars and axes."""


def corner_angles(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Signed interior corner angles ``(E, 4)`` in degrees, in [0, 360)."""
    P = points[quads]                                   # (E, 4, 2)
    e_next = np.roll(P, -1, axis=1) - P
    e_prev = np.roll(P, 1, axis=1) - P
    cross = e_next[..., 0] * e_prev[..., 1] - e_next[..., 1] * e_prev[..., 0]
    dot = np.einsum("eki,eki->ek", e_next, e_prev)
    return np.mod(np.degrees(np.arctan2(cross, dot)), 360.0)


def skewness(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Element skewness ``(E,)``: minimum over corners of ``1 - |theta - 90| / 90``."""
    theta = corner_angles(points, quads)
    return np.min(1.0 - np.abs(theta - 90.0) / 90.0, axis=1)


def signed_area(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Shoelace area ``(E,)``, positive for counter-clockwise quads [m^2]."""
    P = points[quads]
    x, y = P[..., 0], P[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)


def area_change(points_ref: np.ndarray, points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Area ratio ``A / A0`` ``(E,)`` with signed areas."""
    return signed_area(points, quads) / signed_area(points_ref, quads)


def corner_jacobians(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """``cross(e_next, e_prev)`` at each corner ``(E, 4)``: the bilinear map's det J there.

    The bilinear map is one-to-one on the element iff all four are positive.
    """
    P = points[quads]
    e_next = np.roll(P, -1, axis=1) - P
    e_prev = np.roll(P, 1, axis=1) - P
    return e_next[..., 0] * e_prev[..., 1] - e_next[..., 1] * e_prev[..., 0]


def inverted(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Boolean ``(E,)``: the element has a corner with non-positive Jacobian."""
    return np.any(corner_jacobians(points, quads) <= 0.0, axis=1)


@dataclass(frozen=True)
class QualitySummary:
    """Worst-case quality figures of a moved mesh, with where they occur."""

    min_skewness: float
    min_skewness_element: int
    min_skewness_location: tuple[float, float]
    min_area_change: float
    min_area_change_element: int
    max_area_change: float
    max_area_change_element: int
    n_inverted: int
    n_elements: int

    def as_dict(self) -> dict:
        return asdict(self)


def summary(points_ref: np.ndarray, points: np.ndarray, quads: np.ndarray,
            elements: np.ndarray | None = None) -> QualitySummary:
    """Quality summary over ``elements`` (indices into ``quads``; default all).

    Locations are reference-mesh element centres [m].
    """
    ids = np.arange(len(quads)) if elements is None else np.asarray(elements)
    if ids.size == 0:
        raise ValueError("quality summary of an empty element set")
    q = quads[ids]
    skew = skewness(points, q)
    ratio = area_change(points_ref, points, q)
    worst, small, large = int(np.argmin(skew)), int(np.argmin(ratio)), int(np.argmax(ratio))
    centre = points_ref[q[worst]].mean(axis=0)
    return QualitySummary(
        min_skewness=float(skew[worst]), min_skewness_element=int(ids[worst]),
        min_skewness_location=(float(centre[0]), float(centre[1])),
        min_area_change=float(ratio[small]), min_area_change_element=int(ids[small]),
        max_area_change=float(ratio[large]), max_area_change_element=int(ids[large]),
        n_inverted=int(np.sum(inverted(points, q))), n_elements=int(ids.size))
