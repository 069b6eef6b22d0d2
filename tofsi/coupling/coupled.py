"""The coupled fluid-structure-mesh problem: only the fields a scene's effects ask for.

The fields are the entries of :data:`tofsi.core.registry.FIELDS` (:mod:`tofsi.fields`);
a scene's effects decide which are active -- no fluid -> no ``w``; no structure
-> no ``u``; one-way coupling or no mesh motion -> no ``x`` (the flow sees the
reference mesh and the mover is never called). Their blocks go into a
:class:`~tofsi.coupling.block_system.BlockSystem`, which solves them in dependency
order -- one-way: the flow, then the structure; two-way: the cycle flow ->
structure -> mesh -> flow, partitioned (Aitken-relaxed on ``u``) or by
monolithic Newton on

      | S_u  S_x  S_w |
      | D_u  D_x   0  |
      |  0   F_x  F_w |

(see ``docs/design.md``). Continuation parameters are inputs of every solve
(:func:`continuation`). The model owns its linear algebra (the ``[solver]``
table: backend and threads): building a model changes nothing process-wide.
"""

from __future__ import annotations

import time

import numpy as np

from tofsi.coupling.block_system import BlockSystem, CouplingSettings
from tofsi.core.blocks import Continuation, State
from tofsi.mesh.channel import build_mesh
from tofsi.mesh import quality
from tofsi.core.errors import InputError, NumericalError
from tofsi.fields.flow import fluid_force
from tofsi.linalg import LinearAlgebra
from tofsi.coupling.load_ramp import ramped
from tofsi.mesh.structured import DESIGN, SOLID
from tofsi.core.registry import FIELDS

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
                        coupling=pick(d.coupling, ""), structure_model=pick(d.structure_model, ""))


def two_way_stages(scene) -> list[int]:
    """The continuation stages a scene solves two-way (its effects two-way with a mover, and the
    stage's ``design.coupling`` entry not one-way)."""
    e = scene.effects
    if not (e.coupling == "two-way" and e.mesh_motion != "none" and e.structure != "none"):
        return []
    return [k for k in range(scene.design.n_stages) if continuation(scene, k).coupling != "one-way"]


class CoupledModel:
    """Fields, blocks and the coupled solve of a scene (with its design densities).

    fields : the active :class:`~tofsi.fields.base.Field` entries, in dependency order;
    physics : their physics objects by field name (``model.flow``, ``model.structure``
    and ``model.motion`` name the built-in ones, None when absent).
    """

    def __init__(self, scene, mesh=None):
        self.scene = scene
        self.linear_algebra = LinearAlgebra.from_settings(scene.solver)
        self.mesh = build_mesh(scene.geometry, scene.mesh) if mesh is None else mesh
        self.fields = [f for f in FIELDS if f.active(scene, "solve")]
        self.physics: dict = {}
        for field in self.fields:                       # later fields may use earlier physics
            self.physics[field.name] = field.build(self)
        self.force = fluid_force(self)
        self.two_way = "x" in self.physics
        c = scene.coupled
        settings = CouplingSettings(c.method, c.tol, c.max_iter, c.relaxation, relax="u",
                                    quasi_newton=c.quasi_newton, linear_solver=c.linear_solver)
        self.system = self._system(settings, self.two_way)
        self.one_way_system = self._system(settings, False) if self.two_way else self.system
        self.params = continuation(scene)

    def _system(self, settings: CouplingSettings, two_way: bool) -> BlockSystem:
        blocks = [field.block(self, two_way) for field in self.fields]
        return BlockSystem([b for b in blocks if b is not None], settings, self.linear_algebra)

    @property
    def flow(self):
        return self.physics.get("w")

    @property
    def structure(self):
        return self.physics.get("u")

    @property
    def motion(self):
        return self.physics.get("x")

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
        the scene's first stage); ``guess`` warm-starts the solvers. When a two-way solve fails at
        the full inflow from it, the solve continues from the guess's densities (a two-way state of
        another design) or ramps the inflow from rest (``coupled.load_ramp``, :mod:`tofsi.coupling.load_ramp`;
        one-way, the flow continues in its Reynolds number itself)."""
        t0 = time.perf_counter()
        if self.flow is None:
            raise InputError("effects.fluid", "none", "nothing to solve: the scene has no flow")
        params = self.params if params is None else params
        c = self.scene.coupled

        def at(p: Continuation, start: State | None, densities=rho) -> State:
            return self.unfolded(self.system_for(p).solve(densities, p, start, progress))
        system = self.system_for(params)
        coupled = bool(system.cycles)                     # one-way: the flow's Reynolds continuation
        with self.linear_algebra.blas():
            state = (ramped(at, params, guess, c.min_load_step, rho, system.names) if c.load_ramp and coupled
                     else at(params, guess))
        state.reports["wall_time_s"] = time.perf_counter() - t0
        return state

    def unfolded(self, state: State) -> State:
        """``state``, or a :class:`~tofsi.core.errors.NumericalError` when its moved fluid mesh folds:
        an element whose bilinear map is not one-to-one (a corner Jacobian ``<= 0``: an
        inverted or reflex corner, where the flow's element integrals are meaningless). A mover
        may converge to such a mesh (the spring analogy and linear elasticity have no barrier
        against it), so a coupled state is checked before it is used; the load ramp and the
        optimizer's fallbacks then treat the fold as the failure it is."""
        if state.x is None:
            return state
        moved = self.mesh.points + state.mesh_displacement
        folded = np.flatnonzero(quality.inverted(moved, self.mesh.quads))
        if folded.size:
            skew = quality.skewness(moved, self.mesh.quads[folded])
            worst = int(folded[np.argmin(skew)])
            where = self.mesh.centroids[worst]                # on the reference grid
            raise NumericalError(
                f"the moved fluid mesh folds: {folded.size} elements not one-to-one (worst: element {worst} "
                f"near ({where[0]:.3g}, {where[1]:.3g}) m, corner skewness {skew.min():.3f})",
                {"folded_elements": int(folded.size), "element": worst, "location": where.tolist(),
                 "min_skewness": float(skew.min())}, state=state)
        return state

    # ---- figures --------------------------------------------------------------------------
    def figures(self, state: State) -> dict:
        """Every active field's figures of a state (flow: pressure drop, dissipation, drag and
        lift; structure: compliance, largest displacement; moved mesh: its quality)."""
        out = {}
        for field in self.fields:
            out.update(field.figures(self, state))
        return out
