"""Density-based design of a scene: gamma -> rho -> coupled state -> objective and constraints.

    problem = tofsi.Problem(scene)
    gamma = problem.initial_design()
    f, df = problem.evaluate(gamma)          # objective and its gradient
    g, dg = problem.constraints(gamma)       # g <= 0 is feasible, dg: (m, n_design)
    e = problem.evaluation(gamma)            # all of it as one record (what the optimizer reads)

One forward solve and one adjoint solve per quantity at each new design,
cached (keyed by the design and the continuation parameters), because an
optimizer asks for the objective and every constraint at the same point.
The previous state warm-starts the next forward solve, and a two-way solve's
Newton starts from the block factors the previous design's solve left
(:attr:`Problem.factors`, :mod:`tofsi.optimization.carried_factors`): a
solve's result depends only on its inputs, these two included, and both are
in the optimizer's checkpoint (the factors by what they were made of).
The continuation stage -- its numbers (projection sharpness, SIMP penalty,
Brinkman q) and its structure (coupling, the structure's material) -- is one
frozen record, :attr:`Problem.stage`, set whole with :meth:`Problem.set_stage`
(``problem.set_stage(continuation(scene, stage))``) and passed into the design
map and every solve; nothing else holds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from adjoint import Adjoint
from tofsi.core.blocks import Continuation, Stage
from tofsi.coupling.coupled import CoupledModel, State
from tofsi.optimization.carried_factors import CarriedFactors, restore as restore_factors
from tofsi.optimization.design import DesignMap
from tofsi.optimization.design_file import read_design
from tofsi.core.errors import InputError
from tofsi.core.kept import Kept, input_key
from tofsi.mesh.quality import summary as quality_summary
from tofsi.objectives.skewness import SoftMinSkewness
from tofsi.objectives.volume import VolumeFraction
from tofsi.core.registry import OBJECTIVES
from tofsi.optimization.protocol import NO_QUALITY, Evaluation


def mesh_quality(model, state) -> tuple[float, float, float, float]:
    """``(min skewness, min area change, max area change, max interface gap [m])`` of the fluid
    mesh a state's flow was solved on; NaN where the mesh did not move (one-way)."""
    if state.x is None:
        return NO_QUALITY
    mesh = model.mesh
    q = quality_summary(mesh.points, mesh.points + state.mesh_displacement, mesh.quads)
    return q.min_skewness, q.min_area_change, q.max_area_change, model.motion.interface_gap(state.x, state.u, state.rho)


@dataclass(eq=False)
class DesignPoint:
    """One design point: its design variables and coupled state, and what is derived from them
    on first use (the adjoint, the objective and the constraints with their gradients)."""

    gamma: np.ndarray
    state: State
    adjoint: Adjoint | None = None
    objective: tuple | None = None
    constraints: tuple | None = None


class Problem:
    """The design problem of a scene with a design region (a
    :class:`~tofsi.optimization.protocol.DesignProblem`)."""

    def __init__(self, scene, mesh=None):
        if not scene.has_design:
            raise InputError("geometry.design", [], "a design problem needs a design region")
        self.scene = scene
        self.model = CoupledModel(scene, mesh)
        d = scene.design
        self.stage: Stage = self.model.stage
        self.map = DesignMap(self.model.mesh, d.filter_radius, d.eta, d.filter_kernel, d.filter_fixed)
        objective = OBJECTIVES.get(d.objective)           # the field it needs is checked with the scene
        self.objective = objective(scene.objective.params.get(d.objective))
        self.volume_fraction = VolumeFraction(self.model.mesh, self.map.design)
        self.kept_point = Kept()
        self._guess: State | None = None
        self.factors: CarriedFactors | None = None     # the last two-way solve's, for the next one
        self.evaluations = 0
        self.initial_design()                      # a bad design.initial fails here, early

    @property
    def n_design(self) -> int:
        return self.map.size

    def initial_design(self) -> np.ndarray:
        """``design.initial`` if given (a saved design, or a number: a uniform design), else
        uniform at the volume bound."""
        path = self.scene.design.initial
        if not path:
            fraction = self.scene.design.volume_fraction
            return np.full(self.n_design, fraction if self.scene.design.constraint == "solid" else 1 - fraction)
        try:
            value = float(path)
        except ValueError:
            return read_design(path, self.n_design)     # checked: shape, finite, in [0, 1]
        if not 0.0 <= value <= 1.0:
            raise InputError("design.initial", path, "a uniform starting design lies in [0, 1]")
        return np.full(self.n_design, value)

    @property
    def params(self) -> Continuation:
        """The numbers of the current stage (projection sharpness, SIMP penalty, Brinkman q, ...)."""
        return self.stage.params

    def set_stage(self, stage: Stage) -> None:
        """Continue with the continuation stage ``stage`` (e.g. ``continuation(scene, k)``, or
        ``problem.stage.with_params(brinkman_q=0.01)``); nothing else changes."""
        if not isinstance(stage, Stage):
            raise TypeError("set_stage takes a Stage record, e.g. tofsi.coupling.coupled.continuation(scene, k)")
        self.stage = stage

    def set_guess(self, state: State | None) -> None:
        """The state the next forward solve starts from."""
        self._guess = state

    def resume_factors(self, table: dict | None, arrays: dict, stage: Stage) -> None:
        """The factors the next forward solve starts from, made again from a checkpoint's key
        (:meth:`CarriedFactors.record`, taken at ``stage``); None: none."""
        self.factors = None if table is None else restore_factors(table, arrays, stage, self.model.system_for(stage))

    # ---- evaluation -------------------------------------------------------------------
    def densities(self, gamma) -> np.ndarray:
        return self.map.forward(np.asarray(gamma, dtype=float), self.params.beta)

    def phase_fraction(self, gamma) -> float:
        """The constrained phase's fraction of the design region (solid, or fluid with
        ``design.constraint = "fluid"``) at the current projection; no solve."""
        solid = float(self.volume_fraction.weights @ self.densities(gamma))
        return solid if self.scene.design.constraint == "solid" else 1.0 - solid

    def feasible(self, gamma, margin: float = 1e-3) -> np.ndarray:
        """``gamma`` if it meets the phase-fraction bound to within ``margin`` (relative), else
        ``clip(gamma - s delta, 0, 1)`` with the smallest shift ``delta`` (bisection, 50 steps)
        that brings the fraction to ``(1 - margin)`` of the bound (``s = +1`` for a solid bound,
        ``-1`` for a fluid one).

        A sharper projection (a new beta) can move a feasible design past the bound; NLopt's
        MMA and CCSAQ then raise the constraint's multiplier to regain feasibility and keep it
        high, descending the constraint uphill in the objective for a whole stage (measured on
        the two-way scene's beta-8 stage: compliance 0.60 -> 7.0 in 15 iterations; 0.60 -> 0.48
        from the shifted start). The shift is a filtering and a projection, no solve."""
        gamma = np.asarray(gamma, dtype=float)
        bound = self.scene.design.volume_fraction * (1.0 - margin)
        if self.phase_fraction(gamma) <= self.scene.design.volume_fraction * (1.0 + margin):
            return gamma                      # MMA's own end-of-stage violations stay as they are
        sign = 1.0 if self.scene.design.constraint == "solid" else -1.0
        lo, hi = 0.0, 1.0
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.phase_fraction(np.clip(gamma - sign * mid, 0.0, 1.0)) > bound else (lo, mid)
        return np.clip(gamma - sign * hi, 0.0, 1.0)

    def solve(self, gamma) -> State:
        """The coupled state of design ``gamma`` (kept for the point)."""
        return self.point(gamma).state

    def point(self, gamma) -> "DesignPoint":
        """The evaluation of design ``gamma`` at the current continuation stage: its state now,
        its adjoint and derivatives on first use. The last point is kept, keyed by ``gamma`` and
        :attr:`stage` (an optimizer asks for the objective and every constraint at one point)."""
        gamma = np.asarray(gamma, dtype=float)
        if gamma.shape != (self.n_design,):
            raise ValueError(f"gamma must have {self.n_design} entries")
        if not np.all(np.isfinite(gamma)):
            raise InputError("gamma", "non-finite", "design variables must be finite")
        return self.kept_point.get(input_key(gamma, self.stage), lambda: self._new_point(gamma))

    def _new_point(self, gamma) -> "DesignPoint":
        carried = self.factors.for_stage(self.stage) if self.factors is not None else None
        state = self.model.solve(self.densities(gamma), self._guess, stage=self.stage, factors=carried)
        self._guess = state.data()
        self.factors = CarriedFactors.of(state, self.stage)
        self.evaluations += 1
        return DesignPoint(gamma.copy(), state)

    def _adjoint(self, point: "DesignPoint") -> Adjoint:
        if point.adjoint is None:
            point.adjoint = Adjoint(self.model.system_for(point.state.stage), point.state)
        return point.adjoint

    def evaluate(self, gamma) -> tuple[float, np.ndarray]:
        """Objective and its gradient with respect to gamma."""
        point = self.point(gamma)
        if point.objective is None:
            point.objective = (self.objective.value(self.model, point.state), self._total(point, self.objective))
        return point.objective

    def constraint_names(self) -> list[str]:
        """The constraints at the current continuation record: the volume bound, and in a stage
        whose mesh moves the mesh-quality bound when ``design.min_skewness`` asks for it."""
        names = ["volume"]
        if self.scene.design.min_skewness > -1.0 and "x" in self.model.system_for(self.stage).names:
            names.append("min skewness")
        return names

    def constraints(self, gamma) -> tuple[np.ndarray, np.ndarray]:
        """``g <= 0`` and ``dg/dgamma`` ``(m, n_design)`` for the :meth:`constraint_names`:

        * volume: ``phase fraction / volume_fraction - 1``, the phase the solid
          (``design.constraint = "solid"``) or the fluid (``"fluid"``: fraction ``1 - solid``)
          of the design region;
        * min skewness: ``min_skewness - KS_p(corner skewness of the moved mesh)``
          (:class:`~tofsi.objectives.skewness.SoftMinSkewness`), its gradient through the
          coupled adjoint (mover, structure, flow).
        """
        point = self.point(gamma)
        if point.constraints is None:
            state = point.state
            d = self.scene.design
            solid = self.volume_fraction.value(self.model, state)
            sign, fraction = (1.0, solid) if d.constraint == "solid" else (-1.0, 1.0 - solid)
            g = [fraction / d.volume_fraction - 1.0]
            dg = [sign * self._total(point, self.volume_fraction) / d.volume_fraction]
            if "min skewness" in self.constraint_names():
                quality = SoftMinSkewness(d.skewness_ks)
                g.append(d.min_skewness - quality.value(self.model, state))
                dg.append(-self._total(point, quality))
            point.constraints = (np.array(g), np.vstack(dg))
        return point.constraints

    def evaluation(self, gamma) -> Evaluation:
        """Objective, constraints, their gradients, the volume, the moved mesh's quality and the
        inflow ramp's counts of design ``gamma`` as one record, with the state's fields."""
        f, df = self.evaluate(gamma)
        g, dg = self.constraints(gamma)
        point = self.point(gamma)
        state = point.state
        ramp = state.reports.get("load_ramp", {})
        return Evaluation(point.gamma, f, df, g, dg, self.volume_fraction.value(self.model, state),
                          mesh_quality(self.model, state),
                          (len(ramp.get("steps", ())), int(ramp.get("cutbacks", 0))), state.data())

    def _total(self, point: "DesignPoint", quantity) -> np.ndarray:
        """``dq/dgamma`` of a quantity (``value``, ``partials``) at a point: the adjoint, then the
        design map's transpose."""
        with self.model.linear_algebra.blas():         # the model's BLAS threads, as its solves
            d_rho = self._adjoint(point).gradient(quantity.partials(self.model, point.state))
        return self.map.transpose(point.gamma, point.state.params.beta, d_rho)

    def volume(self, gamma) -> float:
        """Solid fraction of the design region."""
        return self.volume_fraction.value(self.model, self.solve(gamma))
