"""Prescribed structural motions of the mesh-motion scenes.

The motion is a displacement of every node of the solid elements:

* ``translation`` -- rigid motion ``(0, -t)``;
* ``rotation`` -- rigid clockwise rotation by ``theta`` about the solid's
  area centroid ``c``: ``u = R (X - c) + c - X``, ``R = [[cos, sin], [-sin, cos]]``;
* ``bending`` -- U shape facing down: with ``xi = (x - x_c) / (L/2)`` over
  the solid's extent, the centre line moves ``v = -d xi^2`` and every
  cross-section turns rigidly to stay normal to it (angle ``phi = atan v'``),
  so a point at height ``eta = y - y_c`` moves
  ``(-eta sin phi, v - eta (1 - cos phi))``; the tips move down by ``d``, the
  centre stays, the thickness is kept;
* ``pressure`` -- a cantilever clamped on the channel walls under a uniform
  pressure on its upstream (left-facing) faces, solved with the structure
  block (plane-strain elasticity of the unified domain, the void at the
  scene's ``e_min_ratio``) and scaled so the largest displacement is
  ``tip_displacement``;
* ``fsi`` -- the structure's displacement under the flow: the scene solved
  one-way by the coupled model (:class:`tofsi.coupling.coupled.CoupledModel`, Navier-Stokes
  with Brinkman friction in the solid, the scene's ``structure.load``), scaled to
  ``tip_displacement`` unless ``scale = false``.
"""

from __future__ import annotations

import numpy as np

from tofsi.coupling.coupled import CoupledModel
from tofsi.core.errors import InputError
from tofsi.mesh.structured import SOLID, StructuredQuadMesh
from tofsi.physics.structure import Structure
from tofsi.scene.tables import Effects
from tofsi.mesh.quality import signed_area


def solid_centroid(mesh: StructuredQuadMesh) -> np.ndarray:
    """Area centroid of the solid elements [m]."""
    solid = mesh.region == SOLID
    area = signed_area(mesh.points, mesh.quads[solid])
    return (mesh.centroids[solid] * area[:, None]).sum(axis=0) / area.sum()


def rigid_rotation(points: np.ndarray, centre: np.ndarray, degrees_clockwise: float) -> np.ndarray:
    """Displacement ``(m, 2)`` of a clockwise rotation about ``centre``."""
    t = np.radians(degrees_clockwise)
    R = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
    rel = points - centre
    return rel @ R.T - rel


def u_bending(points: np.ndarray, extent: np.ndarray, tip: float) -> np.ndarray:
    """U-shaped bending facing down over ``extent = [[xmin, ymin], [xmax, ymax]]``."""
    xc, yc = extent.mean(axis=0)
    half = 0.5 * (extent[1, 0] - extent[0, 0])
    xi = (points[:, 0] - xc) / half
    v = -tip * xi**2
    phi = np.arctan(-2.0 * tip * xi / half)
    eta = points[:, 1] - yc
    return np.column_stack([-eta * np.sin(phi), v - eta * (1.0 - np.cos(phi))])


def upstream_pressure_load(mesh: StructuredQuadMesh, pressure: float = 1.0) -> np.ndarray:
    """Nodal forces ``(2 n,)`` of a uniform pressure on left-facing solid faces [N/m]."""
    solid = (mesh.region == SOLID).reshape(mesh.ny, mesh.nx)
    facing = np.zeros_like(solid)
    facing[:, 1:] = solid[:, 1:] & ~solid[:, :-1]          # fluid to the left of a solid element
    e = np.flatnonzero(facing.ravel())
    q = mesh.quads[e]
    height = mesh.points[q[:, 3], 1] - mesh.points[q[:, 0], 1]
    f = np.zeros(2 * mesh.n_nodes)
    np.add.at(f, 2 * q[:, 0], 0.5 * pressure * height)
    np.add.at(f, 2 * q[:, 3], 0.5 * pressure * height)
    return f


def solid_part(mesh: StructuredQuadMesh, u: np.ndarray) -> np.ndarray:
    """``u`` ``(n, 2)`` on the nodes of solid elements, zero elsewhere."""
    out = np.zeros((mesh.n_nodes, 2))
    solid = mesh.nodes_of(SOLID)
    out[solid] = np.asarray(u).reshape(-1, 2)[solid]
    return out


def scaled_to(u: np.ndarray, tip_displacement: float, mode: str) -> np.ndarray:
    """``u`` scaled so that its largest nodal displacement is ``tip_displacement``."""
    peak = np.max(np.linalg.norm(u, axis=1))
    if not np.isfinite(peak) or peak == 0.0:
        raise InputError("deformation.mode", mode, "the load does not move the solid")
    return u * (tip_displacement / peak)


def cantilever_under_pressure(mesh: StructuredQuadMesh, structure, tip_displacement: float) -> np.ndarray:
    """Displacement ``(n, 2)`` of the solid under upstream pressure, scaled to the tip value."""
    solid_nodes = mesh.nodes_of(SOLID)
    clamped = np.concatenate([mesh.side_nodes(s) for s in structure.clamped])
    if np.intersect1d(clamped, solid_nodes).size == 0:
        raise InputError("structure.clamped", list(structure.clamped),
                         "the solid touches none of these channel sides; it cannot be clamped")
    load = upstream_pressure_load(mesh)
    if not np.any(load):
        raise InputError("deformation.mode", "pressure", "the solid has no upstream face to load")
    block = Structure(mesh, structure)
    rho = (mesh.region == SOLID).astype(float)
    u = block.factorize(rho).solve(block.bc.homogenize(load))
    return scaled_to(solid_part(mesh, u), tip_displacement, "pressure")


def structure_under_flow(mesh: StructuredQuadMesh, scene) -> np.ndarray:
    """Displacement ``(n, 2)`` of the solid nodes under the flow: the scene's flow and structure
    solved one-way by the coupled model (whatever its effects say: a mesh-motion scene
    simulates neither)."""
    one_way = scene.with_tables(effects=Effects(fluid="navier-stokes", structure="linear-elastic"))
    model = CoupledModel(one_way, mesh)
    u = solid_part(mesh, model.solve(model.densities()).u)
    d = scene.deformation
    return scaled_to(u, d.tip_displacement, "fsi") if d.scale else u


def prescribed_motion(mesh: StructuredQuadMesh, scene) -> np.ndarray:
    """Displacement ``(n, 2)`` of the solid nodes (zero elsewhere) for a scene's deformation."""
    deformation, structure = scene.deformation, scene.structure
    solid_nodes = mesh.nodes_of(SOLID)
    if solid_nodes.size == 0:
        raise InputError("geometry.solids", [], "a mesh-motion study needs a solid to move")
    u = np.zeros((mesh.n_nodes, 2))
    X = mesh.points[solid_nodes]
    mode = deformation.mode
    if mode == "translation":
        u[solid_nodes, 1] = -deformation.translation
    elif mode == "rotation":
        u[solid_nodes] = rigid_rotation(X, solid_centroid(mesh), deformation.rotation_deg)
    elif mode == "bending":
        u[solid_nodes] = u_bending(X, np.array([X.min(axis=0), X.max(axis=0)]), deformation.bending_tip)
    elif mode == "pressure":
        u = cantilever_under_pressure(mesh, structure, deformation.tip_displacement)
    elif mode == "fsi":
        u = structure_under_flow(mesh, scene)
    else:
        raise InputError("deformation.mode", mode,
                         "allowed here: 'translation', 'rotation', 'bending', 'pressure', 'fsi'")
    return u
