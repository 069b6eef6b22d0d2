"""Mesh-motion studies: a scene's structure motion applied to its fluid mesh.

The study moves the scene's mesh with :class:`~tofsi.physics.mesh_motion.MeshMotion`
-- the same entry point the coupled model uses -- in its explicit-interface
form: the moving quads are the non-solid elements, every solid node follows
the prescribed structure motion (``x = u``), every node on the channel
boundary stays (``x = 0``), and the scene's mover places the rest. Layered
stiffening factors (``mover.layers``) apply to the element layers counted
from the fluid-structure interface.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

import movers
from movers.base import MoveResult
from movers.problem import MotionProblem
from tofsi.mesh import quality
from tofsi.mesh.channel import build_mesh
from tofsi.coupling.deformation import prescribed_motion
from tofsi.core.errors import InputError
from tofsi.linalg import LinearAlgebra
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.physics.mesh_motion import MeshMotion


@dataclass
class MotionSetup:
    mesh: StructuredQuadMesh
    motion: MeshMotion
    prescribed: np.ndarray       # (n, 2) structure motion, zero elsewhere [m]
    scene: object = None         # the scene the motion (its mover, stiffening, band) was built for

    def check_for(self, scene) -> None:
        """A setup moves with the mover of the scene it was built for: refuse another scene
        (another mover would otherwise print this one's figures under its own name)."""
        if self.scene is not None and self.scene != scene:
            raise ValueError(f"this MotionSetup was built for {self.scene.name!r} with the "
                             f"{self.scene.mover.name} mover; make one per scene: motion_setup(scene)")

    @property
    def problem(self) -> MotionProblem:
        """The mover's problem (the moving quads, the prescribed nodes, the stiffening)."""
        return self.motion.base

    @property
    def moving(self) -> np.ndarray:
        """(Em,) element ids of the moving quads."""
        return self.motion.moving

    @property
    def layer(self) -> np.ndarray:
        """(E,) layer number from the interface (0: none)."""
        return self.motion.layer


KEPT_MOTIONS = 4
_motions: OrderedDict = OrderedDict()      # the last few meshes and structure motions


def _mesh_and_motion(scene):
    """Mesh and structure motion, kept for runs that differ only in the mover (studies): keyed by
    every table the motion reads (the flow's and the solver's only for the ``fsi`` mode)."""
    d = scene.deformation
    key = (scene.geometry, scene.mesh, d, scene.structure,
           (scene.fluid, scene.solver, scene.design, scene.coupled) if d.mode == "fsi" else None)
    if key not in _motions:
        mesh = build_mesh(scene.geometry, scene.mesh)
        motion = prescribed_motion(mesh, scene)
        motion.setflags(write=False)
        _motions[key] = (mesh, motion)
        while len(_motions) > KEPT_MOTIONS:
            _motions.popitem(last=False)
    _motions.move_to_end(key)
    return _motions[key]


def motion_setup(scene, prescribed: np.ndarray | None = None) -> MotionSetup:
    """Mesh, mesh motion and prescribed structure motion of a mesh-motion scene."""
    if scene.effects.mesh_motion == "none":
        raise InputError("mover.name", "none", "a mesh-motion study needs a mover; allowed: "
                         + ", ".join(map(repr, movers.available())))
    if prescribed is None:
        mesh, prescribed = _mesh_and_motion(scene)
    else:
        mesh = build_mesh(scene.geometry, scene.mesh)
    size = float(np.max(np.linalg.norm(prescribed, axis=1))) if prescribed.size else 0.0
    return MotionSetup(mesh, MeshMotion(mesh, scene, motion_size=size,
                                        linear_algebra=LinearAlgebra.from_settings(scene.solver)), prescribed,
                       scene)


def run_move(scene, progress=None, setup: MotionSetup | None = None) -> tuple[MotionSetup, MoveResult]:
    """Apply the scene's motion with its mover; raises NumericalError on failure. ``setup``:
    the scene's :func:`motion_setup`, if already made (a setup of another scene is refused)."""
    if setup is not None:
        setup.check_for(scene)
    setup = setup or motion_setup(scene)
    return setup, setup.motion.move(setup.prescribed, progress=progress)


def moved_quality(setup: MotionSetup, displacement: np.ndarray) -> quality.QualitySummary:
    """Quality of the fluid mesh after the move (every movable quad, also those a band holds)."""
    mesh = setup.mesh
    return quality.summary(mesh.points, mesh.points + displacement, mesh.quads, setup.motion.movable)


def move_figures(scene) -> dict:
    """Quality and cost of one move (the runner of mesh-motion studies)."""
    setup, result = run_move(scene)
    q = moved_quality(setup, result.displacement)
    r = result.report
    return {"converged": r.converged, "min_skewness": q.min_skewness,
            "min_area_change": q.min_area_change, "max_area_change": q.max_area_change,
            "n_inverted": q.n_inverted, "wall_time_s": r.wall_time_s, "increments": r.increments,
            "newton_iterations": r.newton_iterations, "linear_solves": r.linear_solves,
            "factorizations": r.factorizations}
