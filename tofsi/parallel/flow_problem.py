"""A flow-only design problem evaluated across MPI ranks: ``gamma -> rho -> w`` by slabs -> ``f, df/dgamma``.

:class:`DistributedFlowProblem` is a :class:`~tofsi.optimization.protocol.DesignProblem`
for a scene whose only physics is the flow (``effects.structure = "none"``,
``effects.mesh_motion = "none"``; an objective summed over the flow's elements,
a :class:`~tofsi.objectives.FlowObjective`): it answers what
:class:`tofsi.optimization.problem.Problem` answers, with the same numbers (to the
solvers' tolerances), but the flow solved and differentiated by slabs
(:class:`~tofsi.parallel.flow_system.DistributedFlow`,
:class:`~tofsi.parallel.flow_adjoint.SlabObjective`).

Replicated on every rank (cheap, and the same on each): the serial
:class:`~tofsi.optimization.problem.Problem`'s mesh, design map (filter and projection),
volume weights and model -- it never solves here -- the design variables ``gamma``
``(n_design,)``, the densities ``rho`` ``(E,)`` and the gradients, which are
E-vectors. Each evaluation gathers the flow's state on rank 0 (its
:class:`~tofsi.optimization.protocol.Evaluation`'s state: the checkpoint, the pictures
and the final figures read it there; the other ranks' evaluations hold none).

Every rank must evaluate the same ``gamma`` at the same stage (collective
calls). ``tofsi optimize`` under ``mpiexec`` runs the serial
:class:`~tofsi.optimization.optimize.Optimizer` on rank 0 over :func:`leading` (each
collective call announced to the other ranks first) while the other ranks
:func:`serve`; scripts may also call every rank alike.

The chain rule is the serial one: ``df/dgamma = (d rho/d gamma)^T df/drho``
(:meth:`tofsi.optimization.design.DesignMap.transpose`: the projection's derivative, then
the filter's transpose), and the volume bound
``g = phase fraction / volume_fraction - 1`` with
``dg/dgamma = +-(d rho/d gamma)^T weights / volume_fraction`` (no solve).
"""

from __future__ import annotations

import logging
from contextlib import contextmanager

import numpy as np

from tofsi.core.blocks import State
from tofsi.core.errors import InputError, NumericalError
from tofsi.core.kept import Kept, input_key
from tofsi.optimization.problem import Problem
from tofsi.optimization.protocol import Evaluation
from tofsi.parallel.flow_adjoint import SlabObjective, check_objective
from tofsi.parallel.flow_system import DistributedFlow

log = logging.getLogger(__name__)


def check(scene) -> None:
    """Refuse, before anything is built, a scene the distributed flow cannot optimize."""
    e = scene.effects
    if e.structure != "none" or e.mesh_motion != "none":
        raise InputError("effects", f"structure = {e.structure!r}, mesh_motion = {e.mesh_motion!r}",
                         "a flow-only scene (structure and mesh_motion 'none') for the distributed flow "
                         "under mpiexec; or solver.linear_solver = 'petsc' (every rank runs the serial "
                         "problem, MUMPS factorizes across them)")
    check_objective(scene.design.objective)


class DistributedFlowProblem:
    """The design problem of a flow-only ``scene``, its flow by slabs on the ranks of ``comm``
    (the velocity block's AMG: ``solver.flow_amg``)."""

    refuse = staticmethod(check)             # what the scene must be (before anything is built)
    factors = None                           # no factors carried between designs: each solve makes its own

    def resume_factors(self, table, arrays, stage) -> None:
        """Nothing to make again: the solves by slabs carry no factors between designs (a
        serial run's record of its own, if the checkpoint holds one, is not used)."""

    def __init__(self, scene, comm=None):
        self.refuse(scene)
        serial = Problem(scene)              # mesh, design map, volume weights, model: replicated, never solved
        self.serial, self.scene = serial, scene
        self.model, self.map, self.objective = serial.model, serial.map, serial.objective
        self.engine = DistributedFlow(self.model.flow, comm, scene.solver.flow_amg)
        self.kept_point = Kept()
        self.evaluations = 0
        self.guess: np.ndarray | None = None     # the next solve's start (a whole w), else the last state
        self.warm = False                        # the engine's state is the last converged one
        self.prepare()

    def prepare(self) -> None:
        """What the objective's adjoint needs beside the flow (here: the flow objective by slabs)."""
        self.slab_objective = SlabObjective(self.engine, self.objective)

    # ---- what needs no solve: the serial problem's, replicated ---------------------------
    @property
    def n_design(self) -> int:
        return self.serial.n_design

    @property
    def stage(self):
        return self.serial.stage

    @property
    def params(self):
        return self.serial.params

    def initial_design(self) -> np.ndarray:
        return self.serial.initial_design()

    def set_stage(self, stage) -> None:
        """The continuation stage of the next evaluations (collective: every rank the same)."""
        self.serial.set_stage(stage)

    def densities(self, gamma) -> np.ndarray:
        return self.serial.densities(gamma)

    def phase_fraction(self, gamma) -> float:
        return self.serial.phase_fraction(gamma)

    def feasible(self, gamma) -> np.ndarray:
        return self.serial.feasible(gamma)

    def constraint_names(self) -> list[str]:
        return self.serial.constraint_names()

    def set_guess(self, state: State | None) -> None:
        """The next solve starts from ``state``'s flow (collective: every rank the same state)."""
        self.guess = None if state is None else np.asarray(state.fields["w"], dtype=float)

    # ---- evaluation, by slabs ----------------------------------------------------------
    def evaluation(self, gamma) -> Evaluation:
        """The evaluation of ``gamma`` at the current stage (collective); the last one is kept,
        keyed by ``gamma`` and the stage. Its state is the gathered flow on rank 0, None elsewhere."""
        gamma = np.array(gamma, dtype=float)
        if gamma.shape != (self.n_design,) or not np.all(np.isfinite(gamma)):
            raise InputError("gamma", f"shape {gamma.shape}", f"{self.n_design} finite design variables")
        return self.kept_point.get(input_key(gamma, self.stage), lambda: self._new_evaluation(gamma))

    def _new_evaluation(self, gamma: np.ndarray) -> Evaluation:
        p, params, stage = self.serial, self.params, self.stage
        rho = p.densities(gamma)                                                       # (E,) replicated
        guess, self.guess = self.guess, None
        try:                                      # from the guess, or the last converged state
            report = self.engine.solve(None, rho, params, w0=guess, warm=self.warm and guess is None)
        except NumericalError:
            self.warm = False                     # the next solve starts from the boundary values
            raise
        self.warm = True
        self.evaluations += 1
        f, d_rho = self.slab_objective.gradient(rho, params)
        df = p.map.transpose(gamma, params.beta, d_rho)
        g, dg, solid = self.volume_bound(gamma, rho)
        w = self.engine.gather()                                                       # rank 0 only
        state = None if w is None else State(rho, {"w": w}, params, True, {"w": report}, stage=stage)
        log.info("distributed evaluation %d: f = %.10g, Newton %d, Krylov %d, transposed %d", self.evaluations,
                 f, report["newton_iterations"], report["krylov_iterations"], self.engine.transposed_iterations)
        return Evaluation(gamma, f, df, g, dg, solid, state=state)

    def volume_bound(self, gamma, rho) -> tuple[np.ndarray, np.ndarray, float]:
        """``(g (1,), dg/dgamma (1, n_design), solid fraction)`` of the volume bound (no solve)."""
        p, d, beta = self.serial, self.scene.design, self.params.beta
        weights = p.volume_fraction.weights
        solid = float(weights @ rho)
        sign, fraction = (1.0, solid) if d.constraint == "solid" else (-1.0, 1.0 - solid)
        g = np.array([fraction / d.volume_fraction - 1.0])
        return g, (sign * p.map.transpose(gamma, beta, weights) / d.volume_fraction)[None, :], solid

    def evaluate(self, gamma) -> tuple[float, np.ndarray]:
        """Objective and its gradient with respect to ``gamma`` (collective)."""
        e = self.evaluation(gamma)
        return e.f, e.df

    def constraints(self, gamma) -> tuple[np.ndarray, np.ndarray]:
        """The volume bound ``g <= 0`` and ``dg/dgamma`` ``(1, n_design)`` (collective)."""
        e = self.evaluation(gamma)
        return e.g, e.dg


class Leader:
    """Rank 0's view of a :class:`DistributedFlowProblem` for the serial optimizer: every
    collective call (a stage, a guess, an evaluation) is broadcast to the ranks in :func:`serve`
    before rank 0 takes its own part; what needs no solve is rank 0's alone."""

    def __init__(self, problem: DistributedFlowProblem, mpi):
        self.problem, self.mpi = problem, mpi
        self.scene, self.model, self.map = problem.scene, problem.model, problem.map
        self.objective = problem.objective

    def _announce(self, command: str, payload) -> None:
        self.mpi.bcast((command, payload), root=0)

    @property
    def n_design(self) -> int:
        return self.problem.n_design

    @property
    def stage(self):
        return self.problem.stage

    @property
    def evaluations(self) -> int:
        return self.problem.evaluations

    def initial_design(self) -> np.ndarray:
        return self.problem.initial_design()

    def densities(self, gamma) -> np.ndarray:
        return self.problem.densities(gamma)

    def phase_fraction(self, gamma) -> float:
        return self.problem.phase_fraction(gamma)

    def feasible(self, gamma) -> np.ndarray:
        return self.problem.feasible(gamma)

    def constraint_names(self) -> list[str]:
        return self.problem.constraint_names()

    def set_stage(self, stage) -> None:
        self._announce("stage", stage)
        self.problem.set_stage(stage)

    @property
    def factors(self):
        return self.problem.factors

    def resume_factors(self, table, arrays, stage) -> None:
        self.problem.resume_factors(table, arrays, stage)

    def set_guess(self, state: State | None) -> None:
        self._announce("guess", None if state is None else State(state.rho, dict(state.fields)))
        self.problem.set_guess(state)

    def evaluation(self, gamma) -> Evaluation:
        gamma = np.array(gamma, dtype=float)
        self._announce("evaluation", gamma)
        return self.problem.evaluation(gamma)


def serve(problem: DistributedFlowProblem, mpi) -> None:
    """The other ranks' loop: take part in every collective call rank 0's :class:`Leader`
    announces, until it says stop. A failed solve fails on every rank alike (its norms are
    global); rank 0's optimizer decides what follows (a fallback), so the loop goes on."""
    act = {"stage": problem.set_stage, "guess": problem.set_guess, "evaluation": problem.evaluation}
    while True:
        command, payload = mpi.bcast(None, root=0)
        if command == "stop":
            return
        try:
            act[command](payload)
        except NumericalError as err:
            log.info("rank %d: the evaluation failed as on every rank (%s)", mpi.rank, err)


@contextmanager
def leading(scene, kind=DistributedFlowProblem):
    """The distributed problem of ``scene`` (of class ``kind``: :class:`DistributedFlowProblem`
    or a subclass) as rank 0 drives it (a :class:`Leader`); on the other ranks :func:`serve`
    runs until rank 0 leaves the block, and the block gets None."""
    kind.refuse(scene)                                    # before petsc4py is needed
    from tofsi.linalg.petsc import unavailable            # lazily: the one optional need
    missing = unavailable()
    if missing:
        raise InputError("petsc4py", "not available", missing)
    from petsc4py import PETSc
    mpi = PETSc.COMM_WORLD.tompi4py()
    problem = kind(scene, PETSc.COMM_WORLD)
    if mpi.rank != 0:
        serve(problem, mpi)
        yield None
        return
    try:
        yield Leader(problem, mpi)
    finally:
        mpi.bcast(("stop", None), root=0)
