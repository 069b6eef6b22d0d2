"""A flow-only design problem evaluated across MPI ranks: ``gamma -> rho -> w`` by slabs -> ``f, df/dgamma``.

:class:`DistributedFlowProblem` answers what :class:`tofsi.optimization.problem.Problem`
answers for a scene whose only physics is the flow (``effects.structure =
"none"``, ``effects.mesh_motion = "none"``; a ``dissipation`` or
``dissipation-strain`` objective) -- :meth:`evaluate` and :meth:`constraints`
-- with the same numbers (to the solvers' tolerances), but the flow solved
and differentiated by slabs (:class:`~tofsi.parallel.flow_system.DistributedFlow`,
:class:`~tofsi.parallel.flow_adjoint.SlabObjective`).

Replicated on every rank (cheap, and the same on each): the serial
:class:`~tofsi.optimization.problem.Problem`'s mesh, design map (filter and projection)
and volume weights -- it never solves here -- the design variables ``gamma``
``(n_design,)``, the densities ``rho`` ``(E,)`` and the gradients, which are
E-vectors. Every rank must call :meth:`evaluate` and :meth:`constraints` with
the same ``gamma`` (collective calls); :mod:`tofsi.parallel.optimize_flow`
broadcasts it from rank 0.

The chain rule is the serial one: ``df/dgamma = (d rho/d gamma)^T df/drho``
(:meth:`tofsi.optimization.design.DesignMap.transpose`: the projection's derivative, then
the filter's transpose), and the volume bound
``g = phase fraction / volume_fraction - 1`` with
``dg/dgamma = +-(d rho/d gamma)^T weights / volume_fraction`` (no solve).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from tofsi.core.errors import InputError
from tofsi.core.kept import Kept, input_key
from tofsi.parallel.flow_adjoint import SLAB_OBJECTIVES, SlabObjective
from tofsi.parallel.flow_system import DistributedFlow
from tofsi.optimization.problem import Problem

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FlowPoint:
    """One evaluated design: objective, its gradient, constraints and theirs, the solve's report."""

    f: float
    df: np.ndarray             # (n_design,)
    g: np.ndarray              # (1,)
    dg: np.ndarray             # (1, n_design)
    volume: float              # solid fraction of the design region
    report: dict


class DistributedFlowProblem:
    """The design problem of a flow-only ``scene``, its flow by slabs on the ranks of ``comm``.

    amg : the velocity block's AMG (``hypre`` or ``gamg``)
    """

    def __init__(self, scene, comm=None, amg: str = "hypre"):
        e = scene.effects
        if e.structure != "none" or e.mesh_motion != "none":
            raise InputError("effects", f"structure = {e.structure!r}, mesh_motion = {e.mesh_motion!r}",
                             "a flow-only scene (structure and mesh_motion 'none') for the distributed optimizer")
        if scene.design.objective not in SLAB_OBJECTIVES:
            raise InputError("design.objective", scene.design.objective,
                             f"one of {list(SLAB_OBJECTIVES)} for the distributed flow")
        self.problem = Problem(scene)          # mesh, design map, volume weights: replicated, no solve here
        self.scene = scene
        self.engine = DistributedFlow(self.problem.model.flow, comm, amg)
        self.objective = SlabObjective(self.engine, self.problem.objective)
        self.kept_point = Kept()
        self.evaluations = 0

    @property
    def params(self):
        return self.problem.params

    def set_stage(self, params) -> None:
        """The continuation record of the next evaluations (as :meth:`Problem.set_stage`)."""
        self.problem.set_stage(params)

    def point(self, gamma) -> FlowPoint:
        """The evaluation of ``gamma`` at the current continuation record (collective); the last
        one is kept, keyed by ``gamma`` and the record."""
        gamma = np.array(gamma, dtype=float)
        if gamma.shape != (self.problem.n_design,) or not np.all(np.isfinite(gamma)):
            raise InputError("gamma", f"shape {gamma.shape}", f"{self.problem.n_design} finite design variables")
        return self.kept_point.get(input_key(gamma, self.params), lambda: self._new_point(gamma))

    def _new_point(self, gamma: np.ndarray) -> FlowPoint:
        p, params = self.problem, self.params
        rho = p.densities(gamma)                                                       # (E,) replicated
        report = self.engine.solve(None, rho, params, warm=self.evaluations > 0)       # the last state starts
        self.evaluations += 1
        f, d_rho = self.objective.gradient(rho, params)
        df = p.map.transpose(gamma, params.beta, d_rho)
        d = self.scene.design
        weights = p.volume_fraction.weights
        solid = float(weights @ rho)
        sign, fraction = (1.0, solid) if d.constraint == "solid" else (-1.0, 1.0 - solid)
        g = np.array([fraction / d.volume_fraction - 1.0])
        dg = (sign * p.map.transpose(gamma, params.beta, weights) / d.volume_fraction)[None, :]
        log.info("distributed evaluation %d: f = %.10g, Newton %d, Krylov %d, transposed %d", self.evaluations,
                 f, report["newton_iterations"], report["krylov_iterations"], self.engine.transposed_iterations)
        return FlowPoint(f, df, g, dg, solid, report)

    def evaluate(self, gamma) -> tuple[float, np.ndarray]:
        """Objective and its gradient with respect to ``gamma`` (collective)."""
        point = self.point(gamma)
        return point.f, point.df

    def constraints(self, gamma) -> tuple[np.ndarray, np.ndarray]:
        """The volume bound ``g <= 0`` and ``dg/dgamma`` ``(1, n_design)`` (collective)."""
        point = self.point(gamma)
        return point.g, point.dg
