"""The structured mesh of a scene's channel, conforming to every rectangle edge, with solid circles.

A circle ``[x, y, r]`` is the staircase of the elements whose centre lies inside
it. The mesh has grid lines at ``x - r, x, x + r`` and ``y - r, y, y + r`` and the
element size ``h_min`` between them, so the staircase is symmetric about the
circle's centre lines: measured on the DFG 2D-1 cylinder (docs/benchmarks_fsi.md),
a staircase on grid lines that miss the centre carries a spurious lift of the
size of the published one, and the symmetric one converges smoothly. The
elements' area fraction inside the circle as a Brinkman density was measured
too and is further from the no-slip drag (every cut element is nearly solid
at a large friction, so the body is the outer staircase).
"""

from __future__ import annotations

import numpy as np

from tofsi.core.errors import InputError
from tofsi.mesh.grading import graded_axis
from tofsi.mesh.structured import DESIGN, FLUID, SOLID, StructuredQuadMesh


def inside(points: np.ndarray, rect) -> np.ndarray:
    """Points ``(m, 2)`` strictly inside the rectangle ``[x0, x1, y0, y1]``."""
    x0, x1, y0, y1 = rect
    return (points[:, 0] > x0) & (points[:, 0] < x1) & (points[:, 1] > y0) & (points[:, 1] < y1)


def distinct(length: float, values) -> int:
    """Distinct positions among ``values`` and the ends of ``[0, length]`` (to 1e-12 length)."""
    cuts = np.unique(np.clip(np.r_[0.0, length, np.asarray(values, float)], 0.0, length))
    return int(np.sum(np.r_[True, np.diff(cuts) > 1e-12 * length]))


def check_lines(geometry, settings, rects) -> None:
    """Refuse, before grading, rectangles whose edges alone need more than ``mesh.max_elements``:
    the mesh has a grid line at every edge, so at least (distinct x - 1) (distinct y - 1)
    elements (grading a hundred thousand rectangles would take hours first)."""
    nx = distinct(geometry.length, [v for r in rects for v in r[:2]]) - 1
    ny = distinct(geometry.height, [v for r in rects for v in r[2:]]) - 1
    if nx * ny > settings.max_elements:
        key = "geometry.solids" if geometry.solids else "geometry.holes"
        raise InputError(key, f"{len(rects)} rectangles", f"their edges need grid lines that make at "
                         f"least {nx:,} x {ny:,} = {nx * ny:,} elements, more than mesh.max_elements = "
                         f"{settings.max_elements:,}; use fewer rectangles (or edges on shared lines)")


def circle_box(circle) -> list[float]:
    """The grid lines of a circle ``[x, y, r]`` as a rectangle's: ``[x - r, x + r, y - r, y + r]``."""
    x, y, r = circle
    return [x - r, x + r, y - r, y + r]


def mesh_axes(geometry, settings) -> tuple[np.ndarray, np.ndarray]:
    """The node coordinates along x and y of the scene's mesh (cheap: no mesh is built)."""
    rects = list(geometry.solids) + list(geometry.holes) + ([geometry.design] if geometry.design else [])
    boxes = [circle_box(c) for c in geometry.circles]
    check_lines(geometry, settings, rects + boxes + [[x, x, y, y] for x, y, _ in geometry.circles])
    features = list(geometry.solids) + boxes
    xs = graded_axis(geometry.length, [v for r in rects + boxes for v in r[:2]] + [c[0] for c in geometry.circles],
                     [tuple(r[:2]) for r in features], settings.h_min, settings.h_max, settings.growth)
    ys = graded_axis(geometry.height, [v for r in rects + boxes for v in r[2:]] + [c[1] for c in geometry.circles],
                     [tuple(r[2:]) for r in features], settings.h_min, settings.h_max, settings.growth)
    return xs, ys


def in_circle(points: np.ndarray, circle) -> np.ndarray:
    """Points ``(m, 2)`` strictly inside the circle ``[x, y, r]``."""
    x, y, r = circle
    return (points[:, 0] - x) ** 2 + (points[:, 1] - y) ** 2 < r * r


def named_solids(geometry, mesh) -> dict[str, np.ndarray]:
    """The elements of each named solid (``geometry.circle_names``, ``geometry.solid_names``): an
    element belongs to the last shape, circles before rectangles, whose inside holds its centre,
    unless a hole takes it (so a rectangle attached to a circle owns the elements they share)."""
    c = mesh.centroids
    owner = np.full(mesh.n_elements, -1)
    # names: none (unnamed shapes) or one per shape
    shapes = ([(name, in_circle(c, circle))
               for name, circle in zip(geometry.circle_names, geometry.circles, strict=False)]
              + [(name, inside(c, rect)) for name, rect in zip(geometry.solid_names, geometry.solids, strict=False)])
    for k, (_, members) in enumerate(shapes):
        owner[members] = k
    for rect in geometry.holes:
        owner[inside(c, rect)] = -1
    return {name: np.flatnonzero(owner == k) for k, (name, _) in enumerate(shapes)}


def build_mesh(geometry, settings) -> StructuredQuadMesh:
    """Mesh of ``geometry`` (a :class:`tofsi.scene.scene.Geometry`) with ``settings`` (MeshSettings).

    Element tags by centre: design rectangle -> DESIGN, circles and solids -> SOLID,
    holes -> FLUID, in that order of precedence (later wins).
    """
    xs, ys = mesh_axes(geometry, settings)
    n_elements = (len(xs) - 1) * (len(ys) - 1)
    if n_elements > settings.max_elements:
        raise InputError("mesh.h_min", settings.h_min,
                         f"gives {n_elements} elements, more than mesh.max_elements = "
                         f"{settings.max_elements}; use a larger h_min/h_max")
    mesh = StructuredQuadMesh(xs, ys)
    region = np.full(mesh.n_elements, FLUID, dtype=np.int8)
    if geometry.design:
        region[inside(mesh.centroids, geometry.design)] = DESIGN
    for circle in geometry.circles:
        region[in_circle(mesh.centroids, circle)] = SOLID
    for rect in geometry.solids:
        region[inside(mesh.centroids, rect)] = SOLID
    for rect in geometry.holes:
        region[inside(mesh.centroids, rect)] = FLUID
    return mesh.with_regions(region)
