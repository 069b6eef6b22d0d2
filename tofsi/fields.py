"""The fields of the coupled problem, registered in :data:`tofsi.registry.FIELDS` (one entry each).

A :class:`Field` entry carries a field's whole story, so adding a field is
its physics module plus its entry here (or in your own module):

* ``active(scene, command)`` -- whether a scene (and a command) asks for it;
* ``tables`` -- the scene tables holding its settings (registered in
  :data:`~tofsi.registry.SCENE_TABLES`; provenance, ``--resume`` and the scene
  reference read them from there);
* ``memory(grid, scene)`` -- its unknowns and their LU fill for the memory guard
  (:mod:`tofsi.memory`), from the mesh's size and the scene's settings alone;
* ``build(model)`` -- its physics object; ``block(model, two_way)`` -- its
  :class:`~tofsi.blocks.FieldBlock` (the coupled model orders and solves the
  blocks; the checkpoint, the adjoint and ``check-gradients`` follow);
* ``figures(model, state)`` -- the numbers it reports (``solve.json``, result
  files), ``summary`` the ones a command prints;
* ``point_data(model, state)`` -- the nodal arrays it writes (VTU, on the Q2
  nodes), ``pictures(model, state)`` -- the pictures it asks for, as data
  (:class:`Picture`: the drivers draw them; physics knows no plotting), and
  ``picture_names`` their names, known before solving (the output-size
  estimate, :mod:`tofsi.output_size`).

Entries are registered in dependency order (a field's physics may use the
physics of the fields before it: the structure is loaded by the flow, the
mesh follows the structure).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofsi import quality
from tofsi.blocks import FieldBlock, State
from tofsi.errors import InputError
from tofsi.mesh import DESIGN, SOLID
from tofsi.physics.fields import FlowField, MotionField, StructureField
from tofsi.physics.flow import Flow
from tofsi.physics.fluid_load import FluidForce
from tofsi.physics.mesh_motion import MeshMotion
from tofsi.physics.structure import Structure
from tofsi.registry import FIELDS

MOTION_ONLY = ("move", "tune")       # commands that move a mesh with a prescribed structure motion


@dataclass(frozen=True)
class GridSize:
    """The size of a scene's structured mesh (``nx`` by ``ny`` quads), known from its axes alone."""

    nx: int
    ny: int

    @property
    def elements(self) -> int:
        return self.nx * self.ny

    @property
    def nodes(self) -> int:
        """Corner (Q1) nodes."""
        return (self.nx + 1) * (self.ny + 1)

    @property
    def nodes9(self) -> int:
        """Q2 nodes (corners, edge midpoints and centres)."""
        return (2 * self.nx + 1) * (2 * self.ny + 1)


@dataclass(frozen=True)
class Memory:
    """What a field adds to a run's memory: its unknowns, the kind of LU fill they make
    (``"flow"`` saddle point or ``"q1-vector"``; :data:`tofsi.memory.FILL`), and its bytes per
    element (element matrices, assembly slots, kernel temporaries)."""

    unknowns: int
    fill: str
    bytes_per_element: float


@dataclass(frozen=True)
class Picture:
    """A picture a field asks for, as data: ``values`` nodal (``kind = "nodal"``, on the corner
    nodes of the state's mesh, solid elements greyed) or per element on ``points``
    (``kind = "mesh"``: the mesh at ``points`` coloured by ``values``)."""

    name: str
    title: str
    label: str
    values: np.ndarray
    kind: str = "nodal"
    cmap: str = "viridis"
    points: np.ndarray | None = None
    vmin: float | None = None
    vmax: float | None = None


def state_points(model, state: State) -> np.ndarray:
    """Corner coordinates ``(n, 2)`` of the mesh a state's flow was solved on [m]."""
    return model.mesh.points if state.x is None else model.mesh.points + state.mesh_displacement


def on_q2_nodes(mesh, values: np.ndarray) -> np.ndarray:
    """Corner (Q1) values ``(n, ...)`` interpolated bilinearly to the Q2 nodes ``(n9, ...)``."""
    return np.asarray(values)[mesh.edges9].mean(axis=1)


class Field:
    """A registry entry: see the module docstring. Subclasses set ``name`` (the block's field
    name), ``title`` (how reports and the memory guard call it), ``tables`` and ``summary``."""

    name: str
    title: str
    tables: tuple[str, ...] = ()
    summary: tuple[str, ...] = ()
    picture_names: tuple[str, ...] = ()       # the names of what pictures() returns

    def active(self, scene, command: str = "solve") -> bool:
        raise NotImplementedError

    def memory(self, grid: GridSize, scene) -> Memory:
        raise NotImplementedError

    def build(self, model):
        raise NotImplementedError

    def block(self, model, two_way: bool) -> FieldBlock | None:
        raise NotImplementedError

    def figures(self, model, state: State) -> dict:
        return {}

    def point_data(self, model, state: State) -> dict:
        return {}

    def pictures(self, model, state: State) -> list[Picture]:
        return []


class FlowEntry(Field):
    """``w``: Navier-Stokes or Stokes flow with Brinkman friction (Taylor-Hood, or stabilized
    equal order with ``fluid.element = "q1q1"``)."""

    name, title, tables = "w", "flow", ("fluid",)
    summary = ("pressure_drop", "dissipated_power", "drag", "lift")
    picture_names = ("velocity", "pressure")

    def active(self, scene, command="solve"):
        return scene.effects.fluid != "none" and command not in MOTION_ONLY

    def memory(self, grid, scene):
        if scene.fluid.element == "q1q1":       # peaks of a solve at 4005 and 22 578 elements: 182 and
            return Memory(3 * grid.nodes, "flow-q1q1", 1.0e3)       # 670 MB (estimated 1.34x, 1.04x)
        return Memory(2 * grid.nodes9 + grid.nodes, "flow", 1.0e3)   # with the kernel in chunks (fitted)

    def build(self, model):
        return Flow(model.mesh, model.scene.fluid, stokes=model.scene.effects.fluid == "stokes",
                    linear_algebra=model.linear_algebra)

    def block(self, model, two_way):
        return FlowField(model.flow, moving_mesh=two_way)

    def figures(self, model, state):
        """Pressure drop, dissipation and, where there is a solid, drag and lift: the resultant
        of the fluid load on the solid phase [N/m]."""
        if state.w is None:
            return {}
        X = state.mesh_displacement
        out = model.flow.figures(state.w, X, state.rho, state.params)
        if model.force is not None:
            out["drag"], out["lift"] = model.force.resultant(state.w, X, state.rho, state.params)
        return out

    def point_data(self, model, state):
        if state.w is None:
            return {}
        flow = model.flow
        v = state.w[:flow.n_velocity].reshape(-1, 2)
        return {"velocity": on_q2_nodes(model.mesh, v) if flow.element.degree == 1 else v,
                "pressure": on_q2_nodes(model.mesh, state.w[flow.n_velocity:])}

    def pictures(self, model, state):
        if state.w is None:
            return []
        speed = np.linalg.norm(model.flow.corner_velocity(state.w), axis=1)
        return [Picture("velocity", "velocity magnitude", "|v| [m/s]", speed),
                Picture("pressure", "pressure", "p [Pa]", state.w[model.flow.n_velocity:], cmap="coolwarm")]


class StructureEntry(Field):
    """``u``: plane-strain elasticity with SIMP, loaded by the flow."""

    name, title, tables = "u", "structure", ("structure",)
    summary = ("compliance", "max_displacement", "max_solid_displacement")
    picture_names = ("deformed",)

    def active(self, scene, command="solve"):
        return scene.effects.structure != "none" and command not in MOTION_ONLY

    def memory(self, grid, scene):
        return Memory(2 * grid.nodes, "q1-vector", 1.0e3)

    def build(self, model):
        if model.flow is None:
            raise InputError("effects.structure", model.scene.effects.structure,
                             "the structure is loaded by the flow; set effects.fluid too")
        return Structure(model.mesh, model.scene.structure, model.flow, linear_algebra=model.linear_algebra)

    def block(self, model, two_way):
        return StructureField(model.structure, moving_mesh=two_way)

    def figures(self, model, state):
        if state.u is None:
            return {}
        return model.structure.figures(state.u, state.w, state.mesh_displacement, state.rho, state.params)

    def point_data(self, model, state):
        if state.u is None:
            return {}
        return {"structure_displacement": on_q2_nodes(model.mesh, state.u.reshape(-1, 2))}

    def pictures(self, model, state):
        """The structure on its displaced nodes, magnified to a tenth of the channel where the
        motion is small (at most 1 where the mesh moved with it)."""
        if state.u is None:
            return []
        mesh = model.mesh
        U = state.u.reshape(-1, 2)
        scale = 0.1 * np.ptp(mesh.points, axis=0).max() / max(np.abs(U).max(), 1e-300)
        scale = min(scale, 1.0) if state.x is not None else scale
        size = f"magnified {scale:.3g} times" if scale >= 1 else f"drawn at {scale:.3g} of its size"
        return [Picture("deformed", f"structure displacement ({size})",
                        "density rho (0 fluid, 1 solid)", state.rho, kind="mesh", cmap="Greys",
                        points=mesh.points + scale * U, vmin=0.0, vmax=1.0)]


class MotionEntry(Field):
    """``x``: the fluid mesh's displacement, moved by the scene's mover (two-way coupling, or
    the mesh-motion commands' prescribed structure motion)."""

    name, title, tables = "x", "mesh motion", ("mover",)
    summary = ("min_skewness", "n_inverted", "max_interface_gap")
    picture_names = ("mesh",)

    def active(self, scene, command="solve"):
        e = scene.effects
        if e.mesh_motion == "none":
            return False
        if command in MOTION_ONLY:
            return True
        return e.coupling == "two-way" and e.fluid != "none" and e.structure != "none"

    def memory(self, grid, scene):
        return Memory(2 * grid.nodes, "q1-vector", 2.15e3)

    def build(self, model):
        return MeshMotion(model.mesh, model.scene, linear_algebra=model.linear_algebra)

    def block(self, model, two_way):
        return MotionField(model.motion) if two_way else None

    def figures(self, model, state):
        """The moved fluid mesh's quality (smallest skewness, area change range, inverted quads)
        and how far it leaves the structure on the solid (``max_interface_gap`` [m])."""
        if state.x is None:
            return {}
        q = quality.summary(model.mesh.points, state_points(model, state), model.mesh.quads)
        gap = {} if state.u is None else {"max_interface_gap": model.motion.interface_gap(state.x, state.u, state.rho)}
        return {"min_skewness": q.min_skewness, "min_area_change": q.min_area_change,
                "max_area_change": q.max_area_change, "n_inverted": q.n_inverted, **gap}

    def point_data(self, model, state):
        if state.x is None:
            return {}
        return {"mesh_displacement": on_q2_nodes(model.mesh, state.mesh_displacement)}

    def pictures(self, model, state):
        if state.x is None:
            return []
        X = state_points(model, state)
        skew = quality.skewness(X, model.mesh.quads)
        return [Picture("mesh", "moved fluid mesh", quality.SKEWNESS_LABEL, skew, kind="mesh",
                        cmap="RdYlGn", points=X, vmin=min(0.0, float(skew.min())), vmax=1.0)]


for _entry in (FlowEntry(), StructureEntry(), MotionEntry()):       # in dependency order
    FIELDS.register(_entry)


def has_solid(mesh) -> bool:
    """Whether a mesh has fixed solid or design elements (that the flow exerts a force on)."""
    return bool(np.isin(mesh.region, (SOLID, DESIGN)).any())


def fluid_force(model) -> FluidForce | None:
    """The fluid's force on the solid phase: the structure's load where there is a structure,
    else a load of the scene's form for the drag and lift figures (None without flow or solid)."""
    if model.structure is not None:
        return model.structure.force
    if model.flow is None or not has_solid(model.mesh):
        return None
    return FluidForce(model.flow, model.scene.structure.load)
