"""The structured mesh of a scene's channel, conforming to every rectangle edge."""

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


def mesh_axes(geometry, settings) -> tuple[np.ndarray, np.ndarray]:
    """The node coordinates along x and y of the scene's mesh (cheap: no mesh is built)."""
    rects = list(geometry.solids) + list(geometry.holes) + ([geometry.design] if geometry.design else [])
    check_lines(geometry, settings, rects)
    xs = graded_axis(geometry.length, [v for r in rects for v in r[:2]],
                     [tuple(r[:2]) for r in geometry.solids],
                     settings.h_min, settings.h_max, settings.growth)
    ys = graded_axis(geometry.height, [v for r in rects for v in r[2:]],
                     [tuple(r[2:]) for r in geometry.solids],
                     settings.h_min, settings.h_max, settings.growth)
    return xs, ys


def build_mesh(geometry, settings) -> StructuredQuadMesh:
    """Mesh of ``geometry`` (a :class:`tofsi.scene.scene.Geometry`) with ``settings`` (MeshSettings).

    Element tags by centre: design rectangle -> DESIGN, solids -> SOLID,
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
    for rect in geometry.solids:
        region[inside(mesh.centroids, rect)] = SOLID
    for rect in geometry.holes:
        region[inside(mesh.centroids, rect)] = FLUID
    return mesh.with_regions(region)
