"""The coupled fluid-structure-mesh problem: only the fields a scene's effects ask for.

The fields are the entries of :data:`tofsi.core.registry.FIELDS` (:mod:`tofsi.fields`);
a scene's effects decide which are active -- no fluid -> no ``w``; no structure
-> no ``u``; one-way coupling or no mesh motion -> no ``x`` (the flow sees the
reference mesh and the mover is never called). Their blocks go into a
:class:`~tofsi.coupling.block_system.BlockSystem`, which solves them in dependency
order -- one-way: the flow, then the structure; two-way: the cycle flow ->
structure -> mesh -> flow, partitioned (sweeps, ``u``'s next value by IQN-ILS) or by
monolithic Newton on

      | S_u  S_x  S_w |
      | D_u  D_x   0  |
      |  0   F_x  F_w |

(see ``docs/design.md``). A continuation stage (:func:`continuation`) is an input
of every solve: the model reads its structure -- the coupling, the structure's
material -- to choose the block system, whose residuals read its numbers. The
model owns its linear algebra (the ``[solver]`` table: backend and threads):
building a model changes nothing process-wide.
"""

from __future__ import annotations

import time

import numpy as np

from tofsi.coupling.block_system import BlockSystem, CouplingSettings
from tofsi.core.blocks import Continuation, Stage, State
from tofsi.mesh.channel import build_mesh
from tofsi.mesh import quality
from tofsi.core.errors import InputError, NumericalError
from tofsi.fields.flow import fluid_force
from tofsi.linalg import LinearAlgebra
from tofsi.coupling.load_ramp import ramped
from tofsi.coupling.probes import probe_figures
from tofsi.mesh.structured import DESIGN, SOLID
from tofsi.core.registry import FIELDS

__all__ = ["CoupledModel", "Stage", "State", "continuation"]


def continuation(scene, stage: int = 0) -> Stage:
    """Continuation stage ``stage`` of a scene's optimization (stage 0: what ``tofsi solve``
    uses): its numbers and its structure. Each schedule keeps its last value beyond its end."""
    d = scene.design

    def pick(schedule, default):
        return schedule[min(stage, len(schedule) - 1)] if schedule else default
    defaults = Continuation()
    params = Continuation(penalty=float(pick(d.penalty, defaults.penalty)),
                          brinkman_q=float(pick(d.brinkman_q, defaults.brinkman_q)),
                          beta=float(pick(d.beta, defaults.beta)),
                          load_exponent=scene.structure.load_exponent)
    return Stage(params, coupling=pick(d.coupling, ""), material=pick(d.structure_model, ""))


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
    and ``model.motion`` name the built-in ones, None when absent);
    stage : the scene's first continuation stage (what ``tofsi solve`` uses);
    system : its block system (:meth:`system_for` gives any stage's).
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
        self.settings = CouplingSettings(c.method, c.tol, c.max_iter, c.relaxation, relax="u",
                                         quasi_newton=c.quasi_newton, jacobian_solver=c.jacobian_solver)
        self.systems: dict = {}
        self.stage = continuation(scene)
        self.system = self.system_for(self.stage)

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
    def blocks_of(self, stage: Stage) -> Stage:
        """The structure a stage asks of this model: its coupling (``"two-way"`` only where the
        model has a moving mesh and the stage does not ask for one-way) and the structure's
        material (the scene's ``structure.model`` unless the stage names one); no numbers."""
        two_way = self.two_way and stage.coupling != "one-way"
        return Stage(coupling="two-way" if two_way else "one-way",
                     material=stage.material or self.scene.structure.model)

    def system_for(self, stage: Stage) -> BlockSystem:
        """The block system of a stage (a two-way problem's one-way stage: no mesh; the
        structure's block of the stage's material), built once per structure."""
        key = self.blocks_of(stage)
        if key not in self.systems:
            blocks = [field.block(self, key) for field in self.fields]
            self.systems[key] = BlockSystem([b for b in blocks if b is not None], self.settings,
                                            self.linear_algebra)
        return self.systems[key]

    def solve(self, rho: np.ndarray, guess: State | None = None, progress=None,
              stage: Stage | None = None, factors: dict | None = None) -> State:
        """The coupled state for densities ``rho`` (E,) at continuation ``stage`` (default: the
        scene's first); ``guess`` warm-starts the solvers. When a two-way solve fails at the
        full inflow from it, the solve continues from the guess's densities (a two-way state of
        another design) or ramps the inflow from rest (``coupled.load_ramp``,
        :mod:`tofsi.coupling.load_ramp`; one-way, the flow continues in its Reynolds number itself).
        ``factors``: a cycle's linear solver (by the cycle's names) whose factors the solve at
        the full inflow from ``guess`` starts from (the previous design's,
        :mod:`tofsi.optimization.carried_factors`); the continuations build their own."""
        t0 = time.perf_counter()
        if self.flow is None and self.structure is None:
            raise InputError("effects.fluid", "none", "nothing to solve: the scene has no flow and no structure")
        stage = self.stage if stage is None else stage
        c = self.scene.coupled
        with self.linear_algebra.blas():
            system = self.system_for(stage)

            def at(p: Continuation, start: State | None, densities=rho, direct: bool = False,
                   tol: float | None = None, load_step: bool = False) -> State:
                first = start is guess and densities is rho and p is stage.params and not load_step
                return self.unfolded(system.solve(densities, p, start, progress, direct=direct, tol=tol,
                                                  load_step=load_step, factors=factors if first else None))
            try:
                state = (ramped(at, stage.params, guess, c.min_load_step, rho, system.names,
                                inflow_fields=tuple(n for n in system.names if n == "w"))
                         if c.load_ramp and system.cycles
                         else at(stage.params, guess))     # one-way: the flow's Reynolds continuation instead
            except NumericalError as err:
                self._add_quality(err)
                raise
        state.stage = stage
        state.reports["wall_time_s"] = time.perf_counter() - t0
        return state

    def _add_quality(self, err: NumericalError) -> None:
        """A failed load ramp's diagnostic without the mesh's quality gets that of its last
        converged state (the mesh as far as it moved; the command line's --json reports it)."""
        if "quality" in err.diagnostic or err.accepted is None or err.accepted.x is None:
            return
        q = quality.summary(self.mesh.points, self.mesh.points + err.accepted.mesh_displacement, self.mesh.quads)
        err.diagnostic["quality"] = {"load": err.diagnostic.get("load"), "min_skewness": q.min_skewness,
                                     "min_area_change": q.min_area_change, "max_area_change": q.max_area_change,
                                     "n_inverted": q.n_inverted, "worst_element": q.min_skewness_element,
                                     "worst_location": list(q.min_skewness_location)}

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
        lift; structure: compliance, largest displacement; moved mesh: its quality) and the
        scene's probes (:mod:`tofsi.probes`)."""
        out = {}
        for field in self.fields:
            out.update(field.figures(self, state))
        out.update(probe_figures(self, state))
        return out
