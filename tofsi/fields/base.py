"""What every field of the coupled problem is: a :class:`Field` entry of :data:`tofsi.core.registry.FIELDS`.

A field is one module (:mod:`tofsi.fields.flow`, :mod:`~tofsi.fields.structure`,
:mod:`~tofsi.fields.motion`, or a module of your own) holding its whole story:
its settings record and scene table, its block and linearization (the
:mod:`tofsi.core.blocks` protocol, adapting its physics object) and its
:class:`Field` entry, which carries

* ``active(scene, command)`` -- whether a scene (and a command) asks for it;
* ``tables`` -- the scene tables holding its settings (:class:`~tofsi.scene.tables.SceneTable`
  entries: scene loading, provenance, ``--resume`` and the scene reference read
  them from the field, beside the scene's own tables);
* ``memory(grid, scene)`` -- its unknowns and their LU fill for the memory guard
  (:mod:`tofsi.runs.memory`), from the mesh's size and the scene's settings alone;
* ``build(model)`` -- its physics object (the physics is imported there, so loading a
  scene imports no physics); ``block(model, two_way)`` -- its
  :class:`~tofsi.core.blocks.FieldBlock` (the coupled model orders and solves the
  blocks; the checkpoint, the adjoint and ``check-gradients`` follow);
* ``check(model, state)`` -- why a solved state is no physical one (warnings; a
  state that is a failure raises);
* ``figures(model, state)`` -- the numbers it reports (``solve.json``, result
  files), ``summary`` the ones a command prints;
* ``point_data(model, state)`` -- the nodal arrays it writes (VTU, on the Q2
  nodes), ``pictures(model, state)`` -- the pictures it asks for, as data
  (:class:`Picture`: the drivers draw them; physics knows no plotting), and
  ``picture_names`` their names, known before solving (the output-size
  estimate, :mod:`tofsi.runs.output_size`).

Entries are registered in dependency order (a field's physics may use the
physics of the fields before it: the structure is loaded by the flow, the
mesh follows the structure).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofsi.core.blocks import FieldBlock, Linearization, State

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
    (``"flow"`` saddle point or ``"q1-vector"``; :data:`tofsi.runs.memory.FILL`), and its bytes per
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
    tables: tuple = ()                        # SceneTable entries of its settings
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

    def check(self, model, state: State) -> list[str]:
        """Why ``state`` is no physical state of this field (one sentence each; none: it is one).
        A state that is a failure, not an answer, raises :class:`~tofsi.core.errors.NumericalError`."""
        return []

    def figures(self, model, state: State) -> dict:
        return {}

    def point_data(self, model, state: State) -> dict:
        return {}

    def pictures(self, model, state: State) -> list[Picture]:
        return []


def moved_mesh(fields, inputs) -> np.ndarray | None:
    """The mesh displacement ``(n, 2)`` a block with ``inputs`` sees (None: the reference mesh)."""
    x = fields.get("x") if "x" in inputs else None
    return None if x is None else np.asarray(x).reshape(-1, 2)


class EliminatedLinearization(Linearization):
    """Shared by blocks with constant prescribed values: ``matrix()`` eliminates the Dirichlet
    columns, the partials have zero fixed rows, so ``lam`` counts on the free dofs only.
    Subclasses give ``factor_solve`` and ``factor_solve_transpose`` on the free rows."""

    def factor_solve(self, b):
        raise NotImplementedError

    def factor_solve_transpose(self, b):
        raise NotImplementedError

    def solve(self, b):
        z = self.factor_solve(self.block.homogenize(b))
        z[self.block.fixed] = np.asarray(b)[self.block.fixed]
        return z

    def solve_transpose(self, b):
        z = self.factor_solve_transpose(self.block.homogenize(b))
        z[self.block.fixed] = np.asarray(b)[self.block.fixed]
        return z
