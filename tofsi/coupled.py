"""The coupled fluid-structure-mesh problem: only the fields a scene's effects ask for.

The scene's effects decide which field blocks (:mod:`tofsi.physics.fields`)
exist: no fluid -> no ``w``; no structure -> no ``u``; one-way coupling or no
mesh motion -> no ``x`` (the flow sees the reference mesh and the mover is
never called). The blocks go into a :class:`~tofsi.block_system.BlockSystem`,
which solves them in dependency order -- one-way: the flow, then the
structure; two-way: the cycle flow -> structure -> mesh -> flow, partitioned
(Aitken-relaxed on ``u``) or by monolithic Newton on

      | S_u  S_x  S_w |
      | D_u  D_x   0  |
      |  0   F_x  F_w |

(see ``docs/design.md``). Continuation parameters are inputs of every solve
(:func:`continuation`).
"""

from __future__ import annotations

import time

import numpy as np

from tofsi.block_system import BlockSystem, CouplingSettings
from tofsi.blocks import Continuation, State
from tofsi.channel import build_mesh
from tofsi.errors import InputError
from tofsi.mesh import DESIGN, SOLID
from tofsi.physics.fields import FlowField, MotionField, StructureField
from tofsi.physics.flow import Flow
from tofsi.physics.fluid_load import FluidForce
from tofsi.physics.mesh_motion import MeshMotion
from tofsi.physics.structure import Structure
from tofsi.threads import configure as configure_linear_algebra

__all__ = ["CoupledModel", "State", "continuation"]


def continuation(scene, stage: int = 0) -> Continuation:
    """The continuation parameters of a scene's optimization stage (stage 0: what
    ``tofsi solve`` uses). Each schedule keeps its last value beyond its end."""
    d = scene.design

    def pick(schedule, default):
        return schedule[min(stage, len(schedule) - 1)] if schedule else default
    defaults = Continuation()
    return Continuation(penalty=float(pick(d.penalty, defaults.penalty)),
                        brinkman_q=float(pick(d.brinkman_q, defaults.brinkman_q)),
                        beta=float(pick(d.beta, defaults.beta)),
                        load_exponent=scene.structure.load_exponent,
                        coupling=pick(d.coupling, ""))


class CoupledModel:
    """Fields, blocks and the coupled solve of a scene (with its design densities)."""

    def __init__(self, scene, mesh=None):
        self.scene = scene
        configure_linear_algebra(scene.solver)             # backend and threads ([solver])
        self.mesh = build_mesh(scene.geometry, scene.mesh) if mesh is None else mesh
        e = scene.effects
        self.flow = None if e.fluid == "none" else Flow(self.mesh, scene.fluid, stokes=e.fluid == "stokes")
        self.structure = None
        if e.structure != "none":
            if self.flow is None:
                raise InputError("effects.structure", e.structure,
                                 "the structure is loaded by the flow; set effects.fluid too")
            self.structure = Structure(self.mesh, scene.structure, self.flow)
        has_solid = bool(np.isin(self.mesh.region, (SOLID, DESIGN)).any())
        self.force = (self.structure.force if self.structure is not None else
                      FluidForce(self.flow, scene.structure.load) if self.flow is not None and has_solid else None)
        self.two_way = (e.coupling == "two-way" and e.mesh_motion != "none"
                        and self.structure is not None)
        self.motion = MeshMotion(self.mesh, scene) if self.two_way else None
        blocks = []
        if self.flow is not None:
            blocks.append(FlowField(self.flow, moving_mesh=self.two_way))
        if self.structure is not None:
            blocks.append(StructureField(self.structure, moving_mesh=self.two_way))
        if self.motion is not None:
            blocks.append(MotionField(self.motion))
        c = scene.coupled
        settings = CouplingSettings(c.method, c.tol, c.max_iter, c.relaxation, relax="u",
                                    quasi_newton=c.quasi_newton, linear_solver=c.linear_solver)
        self.system = BlockSystem(blocks, settings)
        self.one_way_system = self.system                  # a two-way problem's one-way stages
        if self.two_way:
            self.one_way_system = BlockSystem([FlowField(self.flow), StructureField(self.structure)], settings)
        self.params = continuation(scene)

    # ---- densities -----------------------------------------------------------------
    @property
    def design_elements(self) -> np.ndarray:
        return np.flatnonzero(self.mesh.region == DESIGN)

    def densities(self, rho_design=None) -> np.ndarray:
        """Element densities: 1 in fixed solid, 0 in fixed fluid, ``rho_design`` in the design region."""
        rho = (self.mesh.region == SOLID).astype(float)
        design = self.design_elements
        if design.size:
            rho[design] = self.scene.design.volume_fraction if rho_design is None else rho_design
        return rho

    # ---- forward solve -------------------------------------------------------------------
    def system_for(self, params: Continuation) -> BlockSystem:
        """The block system a solve at ``params`` uses (a two-way problem's one-way stage: no mesh)."""
        return self.one_way_system if params.coupling == "one-way" else self.system

    def solve(self, rho: np.ndarray, guess: State | None = None, progress=None,
              params: Continuation | None = None) -> State:
        """The coupled state for densities ``rho`` (E,) at continuation ``params`` (default:
        the scene's first stage); ``guess`` warm-starts the solvers."""
        t0 = time.perf_counter()
        if self.flow is None:
            raise InputError("effects.fluid", "none", "nothing to solve: the scene has no flow")
        params = self.params if params is None else params
        state = self.system_for(params).solve(rho, params, guess, progress)
        state.reports["wall_time_s"] = time.perf_counter() - t0
        return state

    # ---- figures --------------------------------------------------------------------------
    def figures(self, state: State) -> dict:
        """Flow and structure figures of a state: pressure drop, dissipation, drag and lift (the
        resultant of the fluid load on the solid, with or without the structure effect),
        compliance, largest displacement."""
        out = {}
        X = state.mesh_displacement
        if self.flow is not None and state.w is not None:
            out.update(self.flow.figures(state.w, X, state.rho, state.params))
            if self.force is not None:                   # the force on the solid phase [N/m]
                out["drag"], out["lift"] = self.force.resultant(state.w, X, state.rho, state.params)
        if self.structure is not None and state.u is not None:
            out.update(self.structure.figures(state.u, state.w, X, state.rho, state.params))
        return out
