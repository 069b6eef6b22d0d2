"""Flow-only topology optimization across MPI ranks: MMA on rank 0, the flow and its adjoint by slabs.

    mpiexec -n 2 python -m tofsi.parallel.optimize_flow SCENE [--set KEY=VALUE ...] \\
        [--iterations N] [--output DIR] [--amg hypre|gamg]

Every rank builds the :class:`~tofsi.parallel.flow_problem.DistributedFlowProblem`
(the replicated mesh, design map and volume weights; its own slab of the flow).
Rank 0 runs NLopt exactly as :class:`tofsi.optimization.optimize.Optimizer` does -- the
stages of the scene's continuation, each from the design shifted into the
volume bound (:meth:`tofsi.optimization.problem.Problem.feasible`), ``f / f(stage start)``
minimized with MMA or CCSAQ from the initial step ``INITIAL_STEP``, the
budget ``optimizer.max_iter`` (``--iterations``) and ``design.stage_iterations``,
and the same early stop on small changes -- and broadcasts each new design
(``n_design`` floats) to the other ranks, which wait in :func:`serve`. Every
rank then filters and projects the design, solves the flow and its adjoint
on its slab; objective and gradients are reduced with ``MPI_Allreduce``, so
rank 0 holds them as every rank does. Rank 0 alone writes ``history.json``
and ``history.csv`` (the serial optimizer's rows), ``design.npy`` and
``result.json`` into ``--output``, and prints one line per evaluation.

Not here (the serial :class:`~tofsi.optimization.optimize.Optimizer` has them): the
optimality-criteria algorithm, fallbacks and bridging stages after a failed
solve (a failure stops the run on every rank), checkpoints and ``resume``,
pictures and VTU output.
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import asdict
from pathlib import Path

import nlopt
import numpy as np

from tofsi.coupling.coupled import continuation
from tofsi.core.errors import InputError
from tofsi.optimization.nlopt_stage import ALGORITHMS, INITIAL_STEP, run_stage, settled
from tofsi.optimization.optimize import Iteration, non_discreteness
from tofsi.runs.output import atomic_write, write_csv, write_json

log = logging.getLogger(__name__)


def check(scene) -> None:
    """Refuse, before anything is built, an optimizer setting this driver does not have."""
    if scene.optimizer.algorithm not in ALGORITHMS:
        raise InputError("optimizer.algorithm", scene.optimizer.algorithm,
                         f"one of {sorted(ALGORITHMS)} for the distributed optimizer (no OC)")


def serve(problem, mpi) -> None:
    """The other ranks' loop: take part in every evaluation rank 0 asks for, until it says stop."""
    while True:
        command, payload = mpi.bcast(None, root=0)
        if command == "stop":
            return
        if command == "stage":
            problem.set_stage(payload)
        else:
            problem.point(payload)


class DistributedOptimizer:
    """Rank 0's NLopt driver over a :class:`DistributedFlowProblem` (the other ranks :func:`serve`)."""

    def __init__(self, problem, output: Path, mpi, on_iteration=None):
        scene = problem.scene
        check(scene)
        self.problem, self.output, self.mpi = problem, Path(output), mpi
        self.settings, self.design = scene.optimizer, scene.design
        self.on_iteration = on_iteration
        self.history: list[Iteration] = []
        self.stop_reason = "max_iter"
        self._t0 = time.perf_counter()

    def _point(self, gamma: np.ndarray):
        self.mpi.bcast(("evaluate", gamma), root=0)
        return self.problem.point(gamma)

    def _set_stage(self, params) -> None:
        self.mpi.bcast(("stage", params), root=0)
        self.problem.set_stage(params)

    def run(self) -> dict:
        """Optimize from the scene's initial design; the other ranks are released at the end."""
        try:
            return self._finish(self._stages())
        finally:
            self.mpi.bcast(("stop", None), root=0)

    def _stages(self) -> np.ndarray:
        p, s, d = self.problem, self.settings, self.design
        gamma = p.problem.initial_design()
        for stage in range(d.n_stages):
            remaining = s.max_iter - len(self.history)
            if remaining <= 0:
                break
            self._set_stage(continuation(p.scene, stage))
            budget = remaining if stage == d.n_stages - 1 else min(remaining, d.stage_iterations)
            gamma = self._nlopt(stage, p.problem.feasible(gamma), budget)
        return gamma

    def _nlopt(self, stage: int, start: np.ndarray, max_evaluations: int) -> np.ndarray:
        first_row, scale, last = len(self.history), [None], [None]

        def evaluate(x):
            x = np.array(x, dtype=float)
            point = self._point(x)
            if last[0] is None or not np.array_equal(last[0], x):
                change = 0.0 if last[0] is None else float(np.max(np.abs(x - last[0])))
                if scale[0] is None:
                    scale[0] = abs(point.f) if point.f != 0 else 1.0
                self._record(stage, point, scale[0], change)
                last[0] = x
            return point

        def objective(x, grad):
            point = evaluate(x)
            if grad.size:
                grad[:] = point.df / scale[0]
            if settled(self.history[first_row:], self.settings):
                raise nlopt.ForcedStop
            return float(point.f / scale[0])

        def constraint(result, x, grad):
            point = evaluate(x)
            result[:] = point.g
            if grad.size:
                grad[:] = point.dg

        found, self.stop_reason = run_stage(self.settings.algorithm, start, INITIAL_STEP, objective, constraint,
                                            1, max_evaluations)
        if found is None:
            log.info("stage %d converged after %d evaluations", stage, len(self.history) - first_row)
            return last[0].copy()
        return found

    def _record(self, stage: int, point, scale: float, change: float) -> None:
        params = self.problem.params
        it = Iteration(len(self.history), stage, float(point.f), float(point.f / scale), point.volume,
                       float(point.g[0]), change, params.beta, params.penalty, params.brinkman_q,
                       time.perf_counter() - self._t0, params.coupling or self.problem.scene.effects.coupling)
        self.history.append(it)
        self._write_history()
        if self.on_iteration:
            self.on_iteration(it, point)

    def _write_history(self) -> None:
        rows = [asdict(h) for h in self.history]
        write_csv(self.output / "history.csv", rows)
        write_json(self.output / "history.json", rows)

    def _finish(self, gamma: np.ndarray) -> dict:
        point, p = self._point(gamma), self.problem.problem
        figures = {"scene": self.problem.scene.name, "iterations": len(self.history), "objective": point.f,
                   "volume": point.volume, "constraint": float(point.g[0]),
                   "non_discreteness_percent": non_discreteness(p.densities(gamma)[p.map.design]),
                   "stop_reason": self.stop_reason,
                   "ranks": self.mpi.size, "elements": p.model.mesh.n_elements,
                   "evaluations_computed": self.problem.evaluations,
                   "wall_time_s": time.perf_counter() - self._t0}
        self._write_history()
        atomic_write(self.output / "design.npy", lambda tmp: np.save(tmp, gamma))
        write_json(self.output / "result.json", figures)
        return figures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tofsi.parallel.optimize_flow",
                                     description="Flow-only topology optimization across MPI ranks (PETSc).")
    parser.add_argument("scene")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override")
    parser.add_argument("--iterations", type=int, help="optimizer.max_iter: evaluations in all")
    parser.add_argument("--output", type=Path, default=Path("results/distributed"), help="output folder")
    parser.add_argument("--amg", default="hypre", choices=["hypre", "gamg"])
    args = parser.parse_args(argv)
    from petsc4py import PETSc

    import tofsi
    from tofsi.parallel.flow_problem import DistributedFlowProblem
    overrides = args.set + ([f"optimizer.max_iter={args.iterations}"] if args.iterations else [])
    mpi = PETSc.COMM_WORLD.tompi4py()
    scene = tofsi.load_scene(args.scene, overrides)
    check(scene)
    problem = DistributedFlowProblem(scene, amg=args.amg)
    if mpi.rank != 0:
        serve(problem, mpi)
        return 0
    args.output.mkdir(parents=True, exist_ok=True)

    def line(it, point):
        print(f"{it.iteration:4d}  stage {it.stage}  f {it.objective:.10g}  volume {it.volume:.4f}  "
              f"g {it.constraint:+.2e}  change {it.change:.3f}  Newton {point.report['newton_iterations']}",
              flush=True)
    figures = DistributedOptimizer(problem, args.output, mpi, line).run()
    print(f"{figures['iterations']} evaluations on {mpi.size} ranks: objective {figures['objective']:.10g}, "
          f"{figures['wall_time_s']:.1f} s; {args.output}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
