"""The mesh a mover works on: its nodes, moving quads, fixed nodes and per-quad data.

A :class:`MotionProblem` is built once per mesh and region (``from_mesh`` for a
structured mesh) and holds what every mover reads: the reference points, the
moving quads, the nodes whose displacement is prescribed (every node no moving
quad uses among them), the stiffening factor per quad, the solid indicator of the
density-blended form, and the operators derived from them once (element dofs,
the Dirichlet operator, the nested-dissection ordering). ``with_data`` gives the
same mesh with other factors or blend, keeping those operators.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tofsi.fem.assembly import element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.linalg import nested_dissection


@dataclass(frozen=True, eq=False)
class MotionProblem:
    """The mesh a mover works on.

    points : (n, 2) reference node coordinates [m]
    quads : (Em, 4) the moving quads, counter-clockwise
    fixed_nodes : nodes whose displacement is prescribed
    stiffening : (Em,) stiffness factor per moving quad (layered stiffening)
    grid : (n, 2) integer fine-grid positions of the nodes (for the LU ordering), optional
    blend : (n,) solid indicator per node for the density-blended form
        (see :mod:`movers.blend`); then the prescribed motion is the structural
        displacement of every node, and ``fixed_nodes`` are held at theirs
    accept_inverted : return a mesh with inverted quads (reported in the quality
        records) instead of raising; for studies of the map itself, e.g. tuning
        (a mover whose equations break down at inversion still raises)
    linear_algebra : the model's :class:`tofsi.linalg.LinearAlgebra` (direct backend and
        threads), None for the process default
    element_ids : (Em,) the mesh's number of each moving quad (what diagnostics name);
        default ``0 .. Em-1``
    """

    points: np.ndarray
    quads: np.ndarray
    fixed_nodes: np.ndarray
    stiffening: np.ndarray | None = None
    grid: np.ndarray | None = None
    blend: np.ndarray | None = None
    accept_inverted: bool = False
    linear_algebra: object = None
    element_ids: np.ndarray | None = None

    def __post_init__(self):
        if self.element_ids is None:
            object.__setattr__(self, "element_ids", np.arange(len(self.quads)))
        if len(self.element_ids) != len(self.quads):
            raise ValueError("element_ids needs one number per moving quad")
        n = self.points.shape[0]
        used = np.zeros(n, dtype=bool)
        used[self.quads.ravel()] = True
        fixed = np.union1d(np.asarray(self.fixed_nodes, dtype=np.int64), np.flatnonzero(~used))
        object.__setattr__(self, "fixed_nodes", fixed)
        if self.stiffening is None:
            object.__setattr__(self, "stiffening", np.ones(len(self.quads)))
        if len(self.stiffening) != len(self.quads):
            raise ValueError("stiffening needs one factor per moving quad")
        if np.any(~np.isfinite(self.stiffening)) or np.any(self.stiffening <= 0):
            raise ValueError("stiffening factors must be finite and positive")

    @property
    def n_nodes(self) -> int:
        return self.points.shape[0]

    @cached_property
    def dofs(self) -> np.ndarray:
        """Element dofs ``(Em, 8)``, node-interleaved."""
        return element_dofs(self.quads, 2)

    @property
    def fixed_dofs(self) -> np.ndarray:
        return element_dofs(self.fixed_nodes[:, None], 2).ravel()

    @cached_property
    def bc(self) -> DirichletOperator:
        """The Dirichlet operator of the fixed dofs, built once."""
        return DirichletOperator(self.dofs, self.dofs, 2 * self.n_nodes, self.fixed_dofs)

    def dof_grid(self) -> np.ndarray | None:
        """Grid positions of the dofs (both components of a node share one)."""
        return None if self.grid is None else np.repeat(self.grid, 2, axis=0)

    @cached_property
    def ordering(self) -> np.ndarray | None:
        """Nested-dissection permutation of the dofs, computed once per problem."""
        return None if self.grid is None else nested_dissection(self.dof_grid())

    @classmethod
    def from_mesh(cls, mesh, moving: np.ndarray, fixed_nodes: np.ndarray,
                  stiffening: np.ndarray | None = None, blend: np.ndarray | None = None,
                  linear_algebra=None) -> "MotionProblem":
        """The problem for the quads ``mesh.quads[moving]`` of a structured mesh."""
        i = np.tile(np.arange(mesh.nx + 1), mesh.ny + 1)
        j = np.repeat(np.arange(mesh.ny + 1), mesh.nx + 1)
        return cls(points=mesh.points, quads=mesh.quads[moving], fixed_nodes=fixed_nodes,
                   stiffening=stiffening, grid=np.column_stack([2 * i, 2 * j]), blend=blend,
                   linear_algebra=linear_algebra, element_ids=np.arange(len(mesh.quads))[moving])

    def with_data(self, stiffening=None, blend=None) -> "MotionProblem":
        """The same mesh with other stiffening factors or blend (the cached operators are kept)."""
        other = dataclasses.replace(self, stiffening=self.stiffening if stiffening is None else stiffening,
                                    blend=self.blend if blend is None else blend)
        for key in ("bc", "dofs", "ordering"):
            if key in self.__dict__:
                other.__dict__[key] = self.__dict__[key]
        return other
