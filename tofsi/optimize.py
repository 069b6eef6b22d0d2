"""Topology optimization with NLopt (MMA or CCSAQ), continuation, checkpoints and outputs.

The driver reads top to bottom::

    for each continuation stage (projection beta, SIMP penalty, Brinkman q):
        NLopt minimizes f(gamma) / f(gamma_0) subject to g(gamma) <= 0, 0 <= gamma <= 1,
        each evaluation: one forward solve + one adjoint per quantity (cached),
        after each evaluation: history row, checkpoint, pictures every N iterations.

Resuming is exact. NLopt's MMA keeps internal state that cannot be saved,
so a checkpoint holds every evaluation of the current stage and the last
coupled state; ``resume`` restarts the stage from its first design and
replays the stored evaluations bit for bit (NLopt is deterministic given the
same values) until it passes the interruption, then computes on. Every
computed evaluation creates its own solvers (so its factorizations depend on
nothing earlier) and is warm-started from the previous evaluation's fields,
which a resume restores exactly: the resumed history equals the
uninterrupted one bit for bit. The checkpointed fields are the block
system's (``model.system.names``).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import nlopt
import numpy as np

from tofsi.blocks import State
from tofsi.coupled import continuation
from tofsi import quality
from tofsi.errors import InputError, NumericalError
from tofsi.oc import oc_step
from tofsi.output import atomic_write, write_csv, write_json
from tofsi.resume import check_resume, identity, read_checkpoint

log = logging.getLogger(__name__)
ALGORITHMS = {"MMA": nlopt.LD_MMA, "CCSAQ": nlopt.LD_CCSAQ}
MIN_STAGE = 5            # evaluations before a stage may stop on small changes
INITIAL_STEP = 0.05      # MMA's initial asymptote distance (a move limit for the first steps)


@dataclass
class Iteration:
    iteration: int
    stage: int
    objective: float           # unscaled
    scaled_objective: float    # by the stage's first value
    volume: float              # solid fraction of the design region
    constraint: float          # g <= 0 feasible
    change: float              # max |gamma - gamma_previous|
    beta: float
    penalty: float
    brinkman_q: float
    time_s: float
    coupling: str = ""            # one-way stage of a two-way problem, or as the scene
    min_skewness: float = float("nan")        # of the moved fluid mesh (NaN: the mesh did not move)
    min_area_change: float = float("nan")
    max_area_change: float = float("nan")


def stop_reason(result: int) -> str:
    """Why NLopt ended a stage: ``max_iter`` (the evaluation budget) or NLopt's own reason."""
    if result == nlopt.MAXEVAL_REACHED:
        return "max_iter"
    names = {v: k.lower() for k, v in vars(nlopt).items() if k.isupper() and k.endswith(("REACHED", "LIMITED"))}
    return f"nlopt {names.get(result, result)}"


def mesh_quality(mesh, state) -> tuple[float, float, float]:
    """``(min skewness, min area change, max area change)`` of the fluid mesh a state's flow
    was solved on; NaN where the mesh did not move (one-way)."""
    if state.x is None:
        return (float("nan"),) * 3
    q = quality.summary(mesh.points, mesh.points + state.mesh_displacement, mesh.quads)
    return q.min_skewness, q.min_area_change, q.max_area_change


def non_discreteness(rho: np.ndarray) -> float:
    """Measure of non-discreteness ``4 sum rho (1 - rho) / n`` in percent (0: black and white)."""
    return float(400.0 * np.mean(rho * (1.0 - rho)))


@dataclass
class StageRun:
    """The running continuation stage: its number and start, the scale of its objective (its
    first value), its evaluations so far (checkpointed), the evaluations a resume replays, and
    the last evaluation (NLopt asks for the objective and the constraints at one point)."""

    stage: int
    start: np.ndarray
    scale: float | None = None
    log: list = field(default_factory=list)
    replay: list = field(default_factory=list)
    last: tuple | None = None                   # (gamma, entry)


class Optimizer:
    """NLopt-driven design of a :class:`~tofsi.problem.Problem` with checkpoints in ``output``.

    on_iteration : optional callback ``(Iteration) -> None`` (progress lines, tests)
    on_picture : optional callback ``(iteration, gamma, state) -> None`` (pictures, VTU)
    """

    def __init__(self, problem, output: Path, on_iteration=None, on_picture=None):
        self.problem, self.output = problem, Path(output)
        self.scene = problem.scene
        self.settings, self.design = self.scene.optimizer, self.scene.design
        self.on_iteration, self.on_picture = on_iteration, on_picture
        self.history: list[Iteration] = []
        self.run_stage: StageRun | None = None
        self.stop_reason = "max_iter"        # why the last stage ended (see stop_reason())
        self._t0 = time.perf_counter()

    @property
    def checkpoint_path(self) -> Path:
        return self.output / "checkpoint.npz"

    # ---- evaluation with replay --------------------------------------------------------
    def _evaluate(self, gamma: np.ndarray) -> dict:
        run = self.run_stage
        if run.last is not None and np.array_equal(run.last[0], gamma):
            return run.last[1]
        if run.replay:
            stored = run.replay.pop(0)
            if not np.array_equal(stored["gamma"], gamma):
                raise InputError("--resume", str(self.checkpoint_path),
                                 "the checkpoint does not match this scene's optimization path")
            entry = stored
        else:
            entry = self._compute(gamma)
        previous = run.last[0] if run.last is not None else (run.log[-1]["gamma"] if run.log else gamma)
        run.last = (gamma.copy(), entry)
        run.log.append(entry)
        self._record(gamma, entry, float(np.max(np.abs(gamma - previous))))
        return entry

    def _compute(self, gamma: np.ndarray) -> dict:
        p = self.problem
        try:
            f, df = p.evaluate(gamma)
            g, dg = p.constraints(gamma)
        except NumericalError as err:          # the last checkpoint holds the iterations before
            raise NumericalError(f"design iteration {len(self.history)}: {err}",
                                 {"iteration": len(self.history), **err.diagnostic}, state=err.state) from err
        state = p.solve(gamma)
        return {"gamma": gamma.copy(), "f": f, "df": df, "g": g, "dg": dg,
                "volume": p.volume_fraction.value(p.model, state), "quality": mesh_quality(p.model.mesh, state),
                "state": state}

    def _record(self, gamma, entry, change) -> None:
        run = self.run_stage
        if run.scale is None:                   # each stage scales by its first objective value
            run.scale = abs(entry["f"]) if entry["f"] != 0 else 1.0
        params = self.problem.params            # the stage's record, as the problem solved with it
        it = Iteration(len(self.history), run.stage, float(entry["f"]), float(entry["f"] / run.scale),
                       float(entry["volume"]), float(entry["g"][0]), change, params.beta,
                       params.penalty, params.brinkman_q, time.perf_counter() - self._t0,
                       params.coupling or self.scene.effects.coupling, *entry["quality"])
        self.history.append(it)
        if "state" in entry:                           # computed now (not replayed): save
            self._checkpoint(entry["state"])
            for earlier in run.log[:-1]:               # hold one state (and its factorizations)
                earlier.pop("state", None)
            self._write_history()
            if self.on_picture and (it.iteration % self.settings.output_every == 0):
                self.on_picture(it.iteration, gamma, entry["state"])
        if self.on_iteration:
            self.on_iteration(it)

    # ---- checkpoints -----------------------------------------------------------------
    def _checkpoint(self, state: State) -> None:
        run = self.run_stage
        log_arrays = {}
        for k, e in enumerate(run.log):
            for key in ("gamma", "df", "g", "dg"):
                log_arrays[f"e{k}_{key}"] = e[key]
            log_arrays[f"e{k}_f"] = np.array([e["f"], e["volume"]])
            log_arrays[f"e{k}_quality"] = np.array(e["quality"])
        fields = {f"state_{k}": v for k, v in state.fields.items() if v is not None}
        meta = {"scene": self.scene.name, "stage": run.stage, "n_stage_evaluations": len(run.log),
                "scale": run.scale, "history": [asdict(h) for h in self.history],
                "stage_start": run.start.tolist(),
                "identity": identity(self.scene, self.problem.model.mesh, self.problem.n_design)}

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, meta=np.array(json.dumps(meta)), rho=state.rho, **fields, **log_arrays)
        atomic_write(self.checkpoint_path, write)

    def _load_checkpoint(self):
        meta, data = read_checkpoint(self.checkpoint_path)     # same scene and mesh, or InputError
        check_resume(meta, data, self.problem, self.checkpoint_path)
        replay = []
        for k in range(meta["n_stage_evaluations"]):
            f, volume = data[f"e{k}_f"]
            replay.append({"gamma": data[f"e{k}_gamma"], "df": data[f"e{k}_df"], "g": data[f"e{k}_g"],
                           "dg": data[f"e{k}_dg"], "f": float(f), "volume": float(volume),
                           "quality": tuple(float(q) for q in data.get(f"e{k}_quality", [np.nan] * 3))})
        state = State(rho=data["rho"], converged=True,
                      fields={k[len("state_"):]: v for k, v in data.items() if k.startswith("state_")})
        return meta, replay, state

    # ---- the run ---------------------------------------------------------------------
    def run(self, resume: bool = False) -> dict:
        """Optimize from the initial design (or the checkpoint); returns the final figures."""
        p, s, d = self.problem, self.settings, self.design
        gamma = p.initial_design()
        resumed = None
        if resume:
            meta, replay, state = self._load_checkpoint()
            skip = meta["history"][-1]["iteration"] + 1 - len(replay)   # the earlier stages' iterations
            self.history = [Iteration(**h) for h in meta["history"][:skip]]
            resumed = StageRun(meta["stage"], np.asarray(meta["stage_start"], dtype=float), meta["scale"],
                               replay=replay)
            p.set_guess(state)
        n_stages = d.n_stages
        for stage in range(resumed.stage if resumed else 0, n_stages):
            remaining = s.max_iter - len(self.history)
            if remaining <= 0:
                break
            p.set_stage(continuation(self.scene, stage))
            if resumed is not None and stage == resumed.stage:
                self.run_stage = resumed              # the stage's start and scale, replayed
            else:                                     # each stage starts within the volume bound
                self.run_stage = StageRun(stage, p.feasible(gamma))
            last_stage = stage == n_stages - 1
            budget = remaining if last_stage else min(remaining, d.stage_iterations)
            gamma = self._run_oc_stage(budget, last_stage) if s.algorithm == "OC" else self._run_stage(budget)
        return self.finish(gamma)

    def _converged(self, stage: int) -> bool:
        """Stop a stage once the design settles: after ``MIN_STAGE`` evaluations, the largest
        change below ``tol_change`` twice in a row, or the relative objective change below
        ``tol_objective`` ``stall_iterations`` times in a row (topFlow's rule with 5 and 1e-3)."""
        h = [it for it in self.history if it.stage == stage]
        s = self.settings
        if len(h) < max(MIN_STAGE, s.stall_iterations + 1):
            return False
        if all(it.change < s.tol_change for it in h[-2:]):
            return True
        f = [it.objective for it in h[-(s.stall_iterations + 1):]]
        return all(abs(b - a) <= s.tol_objective * max(abs(a), 1e-300) for a, b in zip(f, f[1:]))

    def _run_stage(self, max_evaluations: int) -> np.ndarray:
        s, run = self.settings, self.run_stage
        gamma = run.start
        opt = nlopt.opt(ALGORITHMS[s.algorithm], gamma.size)
        opt.set_lower_bounds(np.zeros(gamma.size))
        opt.set_upper_bounds(np.ones(gamma.size))
        opt.set_initial_step(np.full(gamma.size, INITIAL_STEP))

        def objective(x, grad):
            e = self._evaluate(np.asarray(x))
            if grad.size:
                grad[:] = e["df"] / run.scale
            if self._converged(run.stage):
                raise nlopt.ForcedStop
            return float(e["f"] / run.scale)

        def constraint(result, x, grad):
            e = self._evaluate(np.asarray(x))
            result[:] = e["g"]
            if grad.size:
                grad[:] = e["dg"]

        opt.set_min_objective(objective)
        opt.add_inequality_mconstraint(constraint, [1e-8])
        opt.set_maxeval(max_evaluations)
        try:
            gamma = np.asarray(opt.optimize(np.clip(gamma, 0.0, 1.0)))
            self.stop_reason = stop_reason(opt.last_optimize_result())
            return gamma
        except nlopt.ForcedStop:
            log.info("stage %d converged after %d evaluations", run.stage, len(run.log))
            self.stop_reason = "converged"
            return run.last[0].copy()

    def _run_oc_stage(self, max_evaluations: int, last_stage: bool) -> np.ndarray:
        """A stage of optimality-criteria steps (:func:`tofsi.oc.oc_step`) in topFlow's order:
        evaluate, stop if the last stage has settled, step, and end an earlier stage after the
        step (its last design is the next stage's first, evaluated with the next parameters)."""
        run = self.run_stage
        gamma = run.start
        for _ in range(max_evaluations):
            entry = self._evaluate(gamma)
            converged = self._converged(run.stage)
            if converged and last_stage:
                break
            gamma = self._oc_step(gamma, entry)
            if converged:
                break
        else:
            self.stop_reason = "max_iter"
            return gamma
        log.info("stage %d converged after %d evaluations", run.stage, len(run.log))
        self.stop_reason = "converged"
        return gamma

    def _oc_step(self, gamma: np.ndarray, entry: dict) -> np.ndarray:
        """One OC step from an evaluation: the volume bound's gradient (its filter and projection
        included) is the phase's volume weight ``dV``."""
        p, d = self.problem, self.design
        solid = d.constraint == "solid"
        dg = np.asarray(entry["dg"])[0]
        dvolume = np.maximum(dg if solid else -dg, 1e-300)
        return oc_step(gamma, entry["df"], dvolume, p.phase_fraction, d.volume_fraction, solid,
                       self.settings.move_limit)

    def _write_history(self) -> None:
        rows = [asdict(h) for h in self.history]
        write_csv(self.output / "history.csv", rows)
        write_json(self.output / "history.json", rows)

    def finish(self, gamma: np.ndarray) -> dict:
        """Evaluate the final design (after the last stage's parameters) and summarize it."""
        p = self.problem
        state = p.solve(gamma)
        rho = p.densities(gamma)[p.map.design]
        figures = {"scene": self.scene.name, "iterations": len(self.history),
                   "objective": float(p.evaluate(gamma)[0]),
                   "volume": float(p.volume_fraction.value(p.model, state)),
                   "constraint": float(p.constraints(gamma)[0][0]),
                   "non_discreteness_percent": non_discreteness(rho),
                   "wall_time_s": time.perf_counter() - self._t0,
                   "evaluations_computed": p.evaluations, "stop_reason": self.stop_reason,
                   "stage": self.history[-1].stage if self.history else 0,     # of these figures
                   **p.model.figures(state)}
        self._write_history()
        write_json(self.output / "result.json", figures)
        atomic_write(self.output / "design.npy", lambda tmp: np.save(tmp, gamma))
        if self.on_picture:
            self.on_picture("final", gamma, state)
        self.final_state = state
        return figures
