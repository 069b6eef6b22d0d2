"""Topology optimization with NLopt (MMA or CCSAQ), continuation, fallbacks, checkpoints and outputs.

The driver reads top to bottom::

    for each continuation stage (projection beta, SIMP penalty, Brinkman q, coupling):
        NLopt minimizes f(gamma) / f(gamma_0) subject to g(gamma) <= 0, 0 <= gamma <= 1,
        each evaluation: one forward solve + one adjoint per quantity (cached),
        after each evaluation: history row and design.npy (small, first), checkpoint,
        pictures every N iterations; a trial design whose solve fails: back to the last
        good design, MMA restarted with half its move limit (a fallback), at most
        optimizer.max_failures in a row.

A trial design of a soft two-way problem can ask for a motion the mesh cannot
follow (the mover folds an element) or a coupled solve that does not converge
even along the inflow ramp (:mod:`tofsi.coupling.load_ramp`). MMA proposed that design
from its own approximation; the driver stops that NLopt run, restarts MMA from
the last design that solved with half the initial step (``INITIAL_STEP``: its
move limit), and goes on. Fallbacks are counted in the history
(``fallbacks``), on the progress line and in the result; the run stops with
exit status 3 only after ``optimizer.max_failures`` consecutive failures, or
or when a stage's first design fails and cannot be bridged, with the
iteration, the stage and the cause (the mover names the element) in the
message.

A stage's first design can fail too: the previous stage's design, sharpened
by the new stage's projection (or solved two-way for the first time), may
ask for a motion the mesh cannot follow. There is no good design of the new
stage to go back to, so the driver steps back in the continuation instead:
it inserts a *bridging stage* halfway between the two stages' records (the
geometric mean of every continued parameter that differs: beta, the SIMP
penalty, the Brinkman q; the coupling and structure model of the new stage),
optimizes it for ``design.stage_iterations`` and tries the stage again from
its design; bridges may nest, at most ``optimizer.max_failures`` per stage.
Each bridge counts as a fallback; its history rows carry the stage's number
and the bridge's parameters.

Resuming is exact. NLopt's MMA keeps internal state that cannot be saved,
so a checkpoint (:mod:`tofsi.optimization.checkpoint`) holds every evaluation of the
current stage -- failed trials included -- and the last coupled state;
``resume`` restarts the stage from its first design and replays the stored
evaluations bit for bit (NLopt is deterministic given the same values, the
fallbacks too) until it passes the interruption, then computes on. Every
computed evaluation creates its own solvers, except that a two-way Newton
starts from the block factors the previous evaluation left
(:mod:`tofsi.optimization.carried_factors`), and is warm-started from the
previous evaluation's fields; a resume restores both exactly (the factors
made again from the Jacobian points the checkpoint records): the resumed
history equals the uninterrupted one bit for bit. The checkpointed fields are the block
system's (``model.system.names``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

import nlopt
import numpy as np

from tofsi.core.blocks import Stage
from tofsi.optimization.checkpoint import read_factors, resume_stage, write_checkpoint
from tofsi.coupling.coupled import continuation
from tofsi.core.errors import InputError, NumericalError
from tofsi.core.finite import require_finite
from tofsi.optimization.final_state import FILE as FINAL_STATE, write_final_state
from tofsi.optimization.history import Iteration
from tofsi.optimization.nlopt_stage import INITIAL_STEP, run_stage, settled
from tofsi.optimization.oc import oc_step
from tofsi.optimization.protocol import Evaluation, FailedEvaluation
from tofsi.runs.output import atomic_write, write_csv, write_json, write_json_rows
from tofsi.optimization.stages import StageRun, StageStartFailed, bridge

log = logging.getLogger(__name__)


VIOLATED = 1e-3      # a final constraint value g above this is a violated bound (result.json's "violated")


class TrialFailed(Exception):
    """A trial design's coupled solve failed (the cause: ``error``, a NumericalError)."""

    def __init__(self, error: NumericalError):
        super().__init__(str(error))
        self.error = error


def non_discreteness(rho: np.ndarray) -> float:
    """Measure of non-discreteness ``4 sum rho (1 - rho) / n`` in percent (0: black and white)."""
    return float(400.0 * np.mean(rho * (1.0 - rho)))


class Optimizer:
    """NLopt-driven (or OC) design of a problem with checkpoints in ``output``: any
    :class:`~tofsi.optimization.protocol.DesignProblem` -- the serial
    :class:`~tofsi.optimization.problem.Problem`, or the distributed flow's problem driven from
    rank 0 (:func:`tofsi.parallel.flow_problem.leading`).

    on_iteration : optional callback ``(Iteration) -> None`` (progress lines, tests)
    on_picture : optional callback ``(iteration, gamma, state) -> None`` (pictures, VTU)
    on_fallback : optional callback ``(iteration, fallbacks, move limit, error) -> None`` after a
        failed trial design (move limit None: a stage's first design failed; a bridging stage next)
    """

    def __init__(self, problem, output: Path, on_iteration=None, on_picture=None, on_fallback=None):
        self.problem, self.output = problem, Path(output)
        self.scene = problem.scene
        self.settings, self.design = self.scene.optimizer, self.scene.design
        self.on_iteration, self.on_picture, self.on_fallback = on_iteration, on_picture, on_fallback
        self.history: list[Iteration] = []
        self.run_stage: StageRun | None = None
        self.fallbacks = 0                   # failed trial designs in the run
        self.stop_reason = "max_iter"        # why the last stage ended (see stop_reason())
        self._t0 = time.perf_counter()

    @property
    def checkpoint_path(self) -> Path:
        return self.output / "checkpoint.npz"

    # ---- evaluation with replay --------------------------------------------------------
    def _evaluate(self, gamma: np.ndarray) -> Evaluation:
        run = self.run_stage
        if run.last is not None and np.array_equal(run.last.gamma, gamma):
            return run.last
        if run.replay:
            entry = run.replay.pop(0)
            if not np.array_equal(entry.gamma, gamma):
                raise InputError("--resume", str(self.checkpoint_path),
                                 "the checkpoint does not match this scene's optimization path")
        else:
            entry = self._compute(gamma)
        run.log.append(entry)
        if entry.failed:
            raise TrialFailed(NumericalError(entry.error, entry.diagnostic))
        previous = run.last.gamma if run.last is not None else gamma
        run.last, run.failures_in_a_row = entry, 0
        self._record(gamma, entry, float(np.max(np.abs(gamma - previous))))
        return entry

    def _compute(self, gamma: np.ndarray) -> Evaluation | FailedEvaluation:
        p = self.problem
        try:
            e = p.evaluation(gamma)
            require_finite({p.scene.design.objective: e.f, "objective gradient": e.df, "constraints": e.g,
                            "constraint gradients": e.dg, "volume": e.volume, "state": e.state.fields},
                           f"design iteration {len(self.history)}")
        except NumericalError as err:
            return FailedEvaluation(gamma.copy(), str(err), err.diagnostic)
        return e

    def _record(self, gamma, entry: Evaluation, change) -> None:
        run = self.run_stage
        if run.scale is None:                   # each stage scales by its first objective value
            run.scale = abs(entry.f) if entry.f != 0 else 1.0
        stage = self.problem.stage              # the stage's record, as the problem solved with it
        params, g = stage.params, entry.g
        elapsed = entry.time_s                  # a replayed row keeps its recorded time
        it = Iteration(len(self.history), run.stage, float(entry.f), float(entry.f / run.scale),
                       float(entry.volume), float(g[0]), change, params.beta, params.penalty,
                       params.brinkman_q, time.perf_counter() - self._t0 if elapsed is None else elapsed,
                       stage.coupling or self.scene.effects.coupling, *entry.quality,
                       float(g[1]) if len(g) > 1 else float("nan"), self.fallbacks, *entry.ramp)
        require_finite(it.row(), f"the history row of design iteration {it.iteration}")
        self.history.append(it)
        if entry.state is not None:                    # computed now (not replayed): save
            self._write_history()                      # the small results first: a full disk
            self._write_design(gamma)                  # keeps them (the line says so)
            write_checkpoint(self.checkpoint_path, self.problem, run, self.history, entry.state)
            run.log[:-1] = [e if e.failed else replace(e, state=None) for e in run.log[:-1]]   # one state held
            if self.on_picture and (it.iteration % self.settings.output_every == 0):
                self.on_picture(it.iteration, gamma, entry.state, entry.df)
        if self.on_iteration:
            self.on_iteration(it)

    # ---- the run ---------------------------------------------------------------------
    def run(self, resume: bool = False) -> dict:
        """Optimize from the initial design (or the checkpoint); returns the final figures."""
        return self.finish(self.design_after(self.design.n_stages, resume))

    def design_after(self, end: int, resume: bool = False) -> np.ndarray:
        """The design the stages before ``end`` reach (from the initial design, or the
        checkpoint), without the final evaluation and summary of :meth:`run`."""
        p, s, d = self.problem, self.settings, self.design
        gamma = p.initial_design()
        run, previous = None, None
        if resume:                          # the checkpoint's stage, its evaluations to replay
            self.history, self.fallbacks, run, state = resume_stage(self.checkpoint_path, p)
            previous = run.previous
            p.set_guess(state)
            p.resume_factors(*read_factors(self.checkpoint_path, p))
        for stage in range(run.stage if run else 0, end):
            pending = run.pending + [run.record] if run else [continuation(self.scene, stage)]
            while pending:                            # the stage's record, after the bridges it needs
                remaining = s.max_iter - len(self.history)
                if remaining <= 0:
                    return gamma
                record = pending.pop()
                p.set_stage(record)
                if run is None:                       # each stage starts within the volume bound
                    run = StageRun(stage, p.feasible(gamma), fallbacks_at_start=self.fallbacks, record=record,
                                   pending=list(pending), previous=previous, first_row=len(self.history))
                self.run_stage = run                  # (a resumed one: its start and scale, replayed)
                last = stage == d.n_stages - 1 and not pending
                try:
                    budget = remaining if last else min(remaining, d.stage_iterations)
                    gamma = self._run_oc_stage(budget, last) if s.algorithm == "OC" else self._run_stage(budget)
                    previous = record
                except StageStartFailed as failed:
                    pending += [record, self._bridge(previous, record, len(pending), failed.error)]
                run = None
        return gamma

    def _bridge(self, previous: Stage | None, target: Stage, bridges: int, error: NumericalError) -> Stage:
        """The bridging stage to try after the first design of the stage record ``target`` failed
        (``bridges``: those already pending for it), or the run's failure when none is left."""
        halfway = bridge(previous, target) if bridges < self.settings.max_failures else None
        if halfway is None:
            raise error                                   # (the failed trial is counted already)
        h = halfway.params
        log.info("design iteration %d: the first design of stage %d (beta %g) failed (%s); a bridging "
                 "stage at beta %g, penalty %g, q %g first (fallback %d)", len(self.history), self.run_stage.stage,
                 target.params.beta, error, h.beta, h.penalty, h.brinkman_q, self.fallbacks)
        if self.on_fallback:
            self.on_fallback(len(self.history), self.fallbacks, None, error)
        return halfway

    def _converged(self) -> bool:
        """The running stage (or bridge) has settled (:func:`settled` on its rows)."""
        return settled(self.history[self.run_stage.first_row:], self.settings)

    def _run_stage(self, max_evaluations: int) -> np.ndarray:
        """NLopt over the stage, within ``max_evaluations`` evaluations (failed trials count);
        after a failed trial design MMA restarts from the last good design with half its move
        limit, until ``optimizer.max_failures`` failures in a row."""
        run, step = self.run_stage, INITIAL_STEP
        gamma = run.start
        while True:
            budget = max_evaluations - len(run.log)
            if budget <= 0:
                self.stop_reason = "max_iter"
                return run.last.gamma.copy() if run.last is not None else gamma
            try:
                return self._nlopt(gamma, step, budget + (run.last is not None))   # + the restart's repeat
            except TrialFailed as failed:
                self.fallbacks += 1
                run.failures_in_a_row += 1
                self._give_up_unless_fallback(failed.error)
                gamma, step = run.last.gamma, 0.5 * step
                log.info("design iteration %d: a trial design failed (%s); MMA restarts from the last "
                         "good design with move limit %.3g (fallback %d, %d in a row)", len(self.history),
                         failed.error, step, self.fallbacks, run.failures_in_a_row)
                if self.on_fallback:
                    self.on_fallback(len(self.history), self.fallbacks, step, failed.error)

    def _give_up_unless_fallback(self, error: NumericalError) -> None:
        """Raise the run's failure when no fallback is possible: the stage's first design failed,
        or ``optimizer.max_failures`` trial designs failed in a row."""
        run, limit = self.run_stage, self.settings.max_failures
        stage = self.problem.stage
        where = (f"design iteration {len(self.history)} (stage {run.stage}, "
                 f"{stage.coupling or self.scene.effects.coupling}, beta {stage.params.beta:g})")
        diagnostic = {"iteration": len(self.history), "stage": run.stage, "fallbacks": self.fallbacks,
                      "failures_in_a_row": run.failures_in_a_row, **error.diagnostic}
        if run.last is None:
            diagnostic["why"] = ("the stage's first design failed, so there is no good design of this stage to "
                                 "fall back to, and no bridging stage is left (a bridge needs an earlier stage "
                                 "whose beta, penalty or q differs by 5 % or more; at most "
                                 "optimizer.max_failures nested per stage)")
            raise StageStartFailed(NumericalError(
                f"{where}: the stage's first design failed, no bridging stage left; the last: {error}",
                diagnostic, state=error.state))
        if run.failures_in_a_row >= limit:
            raise NumericalError(f"{where}: {run.failures_in_a_row} trial designs failed in a row "
                                 f"(optimizer.max_failures = {limit}); the last: {error}", diagnostic,
                                 state=error.state)

    def _nlopt(self, gamma: np.ndarray, step: float, max_evaluations: int) -> np.ndarray:
        run = self.run_stage

        def objective(x, grad):
            e = self._evaluate(np.asarray(x))
            if grad.size:
                grad[:] = e.df / run.scale
            if self._converged():
                raise nlopt.ForcedStop
            return float(e.f / run.scale)

        def constraint(result, x, grad):
            e = self._evaluate(np.asarray(x))
            result[:] = e.g
            if grad.size:
                grad[:] = e.dg

        found, self.stop_reason = run_stage(self.settings.algorithm, gamma, step, objective, constraint,
                                            len(self.problem.constraint_names()), max_evaluations)
        if found is None:
            log.info("stage %d converged after %d evaluations", run.stage, len(run.log))
            return run.last.gamma.copy()
        return found

    def _run_oc_stage(self, max_evaluations: int, last_stage: bool) -> np.ndarray:
        """A stage of optimality-criteria steps (:func:`tofsi.optimization.oc.oc_step`) in topFlow's order:
        evaluate, stop if the last stage has settled, step, and end an earlier stage after the
        step (its last design is the next stage's first, evaluated with the next parameters).
        A trial design that fails: the step is taken again from the last good design with half
        the move limit (a fallback), until ``optimizer.max_failures`` failures in a row."""
        run = self.run_stage
        gamma, move = run.start, self.settings.move_limit
        for _ in range(max_evaluations):
            try:
                entry = self._evaluate(gamma)
            except TrialFailed as failed:
                self.fallbacks += 1
                run.failures_in_a_row += 1
                self._give_up_unless_fallback(failed.error)
                move *= 0.5
                log.info("design iteration %d: a trial design failed (%s); the OC step again from the last "
                         "good design with move limit %.3g (fallback %d)", len(self.history), failed.error,
                         move, self.fallbacks)
                if self.on_fallback:
                    self.on_fallback(len(self.history), self.fallbacks, move, failed.error)
                gamma = self._oc_step(run.last.gamma, run.last, move)
                continue
            converged = self._converged()
            if converged and last_stage:
                break
            gamma = self._oc_step(gamma, entry, move)
            if converged:
                break
        else:
            self.stop_reason = "max_iter"
            return gamma
        log.info("stage %d converged after %d evaluations", run.stage, len(run.log))
        self.stop_reason = "converged"
        return gamma

    def _oc_step(self, gamma: np.ndarray, entry: Evaluation, move: float) -> np.ndarray:
        """One OC step from an evaluation, changing no variable by more than ``move``: the volume
        bound's gradient (its filter and projection included) is the phase's volume weight ``dV``."""
        p, d = self.problem, self.design
        solid = d.constraint == "solid"
        dg = np.asarray(entry.dg)[0]
        dvolume = np.maximum(dg if solid else -dg, 1e-300)
        return oc_step(gamma, entry.df, dvolume, p.phase_fraction, d.volume_fraction, solid, move)

    def _write_history(self) -> None:
        rows = [h.row() for h in self.history]          # each checked finite when recorded
        write_csv(self.output / "history.csv", rows)
        write_json_rows(self.output / "history.json", rows)

    def _write_design(self, gamma: np.ndarray) -> None:
        """``design.npy``: the design variables of the latest iteration (the final design once
        the run ends), for ``tofsi solve --design``."""
        atomic_write(self.output / "design.npy", lambda tmp: np.save(tmp, gamma))

    def finish(self, gamma: np.ndarray) -> dict:
        """Evaluate the final design (after the last stage's parameters) and summarize it."""
        p = self.problem
        final = p.evaluation(gamma)
        state, g = final.state, final.g
        rho = p.densities(gamma)[p.map.design]
        constraints = dict(zip(p.constraint_names(), map(float, g), strict=True))
        figures = {"scene": self.scene.name, "iterations": len(self.history),
                   "objective": float(final.f), "volume": float(final.volume),
                   "constraint": float(g[0]), "constraints": constraints,
                   "violated": {k: v for k, v in constraints.items() if v > VIOLATED},
                   "non_discreteness_percent": non_discreteness(rho),
                   "wall_time_s": time.perf_counter() - self._t0,
                   "evaluations_computed": p.evaluations, "stop_reason": self.stop_reason,
                   "fallbacks": self.fallbacks,
                   "stage": self.history[-1].stage if self.history else 0,     # of these figures
                   **p.model.figures(state)}
        structure = p.model.structure
        beyond = "" if structure is None else structure.displacement_beyond_channel(state.u, state.rho)
        figures["physical"] = not beyond                 # else the reason (exit 5 on the command line)
        if beyond:
            figures["unphysical"] = beyond
        require_finite(figures, f"the final design (after design iteration {len(self.history) - 1})")
        self._write_history()
        self._write_design(gamma)
        write_final_state(self.output / FINAL_STATE, p, gamma, state, figures["stage"])    # to re-solve it
        write_json(self.output / "result.json", figures)
        if self.on_picture:                # the gradient as recorded (a resumed run has no adjoint of it)
            last = self.run_stage.last if self.run_stage is not None else None
            recorded = last.df if last is not None and np.array_equal(last.gamma, gamma) else final.df
            self.on_picture("final", gamma, state, recorded)
        self.final_state = state
        return figures
