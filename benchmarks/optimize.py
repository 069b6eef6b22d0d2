"""Time and memory of one design iteration on the 180 x 90 beam-in-channel problem.

One iteration = forward solve (Navier-Stokes flow, then the structure), the
adjoint gradients of the objective and of the volume constraint, and NLopt's
MMA update. The script runs a few iterations of the real driver (one-way
coupling, the scene's Reynolds number), reports the mean time per iteration
after the first and where it goes (forward / adjoint / rest), and the peak
memory. Target: at most 4 s per iteration and 4 GB on two cores.

``--floor`` also counts, per iteration after the first, what an iteration is
made of -- fluid kernel passes (with and without the Jacobian), sparse
factorizations and triangular solves (SuperLU or PARDISO), each with its time
-- and prints the iteration's time over its factorizations' (issue 23's "at
its floor": at most 1.5 one-way). ``--two-way`` runs the headline two-way
scene (``beam_in_channel_optimization_fsi``) two-way from its first iteration.

    python benchmarks/optimize.py [--elements-x 180] [--iterations 6] [--backend superlu]
                                  [--blas-threads 1] [--floor] [--two-way]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import platform
import pstats
import resource
import tempfile
import time
from pathlib import Path


SCENES = Path(__file__).resolve().parents[1] / "examples" / "scenes"
SCENE = SCENES / "beam_in_channel_optimization.toml"
TWO_WAY_SCENE = SCENES / "beam_in_channel_optimization_fsi.toml"


class FloorCounter:
    """Counts and times the pieces of an iteration by wrapping, for this process only, the fluid
    kernel (Taylor-Hood), the backends' factorizations and their triangular solves."""

    def __init__(self):
        import collections
        self.count, self.seconds = collections.Counter(), collections.Counter()
        self.marks = []

    def wrap(self, owner, name, label):
        raw = owner.__dict__[name]
        function = raw.__func__ if isinstance(raw, (staticmethod, classmethod)) else raw

        def timed(*a, **k):
            t0 = time.process_time()
            out = function(*a, **k)
            key = label(a, k)
            self.count[key] += 1
            self.seconds[key] += time.process_time() - t0
            return out
        setattr(owner, name, staticmethod(timed) if isinstance(raw, staticmethod) else timed)

    def install(self, backend: str):
        from tofsi.physics import fluid_kernel
        self.wrap(fluid_kernel, "fluid_elements", lambda a, k: "kernel pass" + (
            " (residual only)" if not k.get("jacobian", a[7] if len(a) > 7 else True) else ""))
        module = __import__(f"tofsi.linalg.{backend}", fromlist=["Analysis"])
        self.wrap(module.Analysis, "factorize", lambda a, k: f"factorization, {a[1].shape[0]} unknowns")
        self.wrap(module.Factorization, "solve", lambda a, k: f"triangular solve pair, {len(a[1])} unknowns")

    def mark(self):
        self.marks.append((time.process_time(), dict(self.count), dict(self.seconds)))

    def report(self) -> dict:
        (t0, c0, s0), (t1, c1, s1) = self.marks[1], self.marks[-1]
        n = len(self.marks) - 2
        rows = {k: {"per_iteration": (c1[k] - c0.get(k, 0)) / n, "seconds": (s1[k] - s0.get(k, 0)) / n}
                for k in sorted(c1)}
        factorizations = sum(r["seconds"] for k, r in rows.items() if k.startswith("factorization"))
        per_iteration = (t1 - t0) / n
        return {"seconds_per_iteration": per_iteration, "factorization_s": factorizations,
                "iteration_over_factorizations": per_iteration / factorizations, "pieces": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=180)
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--backend", default="superlu", help="solver.linear_solver (superlu, pardiso, auto, ...)")
    parser.add_argument("--blas-threads", type=int, default=1, help="solver.blas_threads (0: library default)")
    parser.add_argument("--profile", action="store_true", help="print where the time goes")
    parser.add_argument("--floor", action="store_true", help="count kernel passes, factorizations, solves")
    parser.add_argument("--two-way", action="store_true", help="the two-way scene, two-way throughout")
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks"))
    args = parser.parse_args()

    import tofsi
    from tofsi.optimization.optimize import Optimizer
    from tofsi.runs.output import write_json

    h = 2.0 / args.elements_x
    sets = [f"mesh.h_min={h}", f"mesh.h_max={h}", f"optimizer.max_iter={args.iterations}",
            f"design.stage_iterations={args.iterations}", f"solver.linear_solver={args.backend}",
            f"solver.blas_threads={args.blas_threads}"]
    if args.two_way:
        sets.append('design.coupling=["two-way"]')
    scene = tofsi.load_scene(TWO_WAY_SCENE if args.two_way else SCENE, sets)
    problem = tofsi.Problem(scene)
    floor = FloorCounter() if args.floor else None
    if floor:
        floor.install(args.backend)
    times = {"forward": [], "adjoint": []}

    def timed(fn, key):
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            out = fn(*a, **k)
            times[key].append(time.perf_counter() - t0)
            return out
        return wrapper

    import adjoint.solve
    problem.model.solve = timed(problem.model.solve, "forward")
    adjoint.solve.Adjoint.gradient = timed(adjoint.solve.Adjoint.gradient, "adjoint")
    stamps = []
    with tempfile.TemporaryDirectory() as tmp:
        def on_iteration(it):
            stamps.append(time.perf_counter())
            if floor:
                floor.mark()
        optimizer = Optimizer(problem, tmp, on_iteration=on_iteration)
        profiler = cProfile.Profile() if args.profile else None
        if profiler:
            profiler.enable()
        optimizer.run()
        if profiler:
            profiler.disable()
    per_iteration = [b - a for a, b in zip(stamps[:-1], stamps[1:])]
    n = len(per_iteration)
    mean = lambda xs: sum(xs) / max(len(xs), 1)
    row = {"elements": problem.model.mesh.n_elements, "design_variables": problem.n_design,
           "flow_dofs": problem.model.flow.size, "iterations": len(stamps),
           "seconds_per_iteration": mean(per_iteration[1:]),
           "forward_s": mean(times["forward"][2:2 + n]),
           "adjoint_s": mean([a + b for a, b in zip(times["adjoint"][2::2], times["adjoint"][3::2])]),
           "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2,
           "backend": args.backend, "blas_threads": args.blas_threads,
           "machine": f"{platform.machine()}, Python {platform.python_version()}"}
    row["mma_and_rest_s"] = row["seconds_per_iteration"] - row["forward_s"] - row["adjoint_s"]
    row["coupling"] = "two-way" if args.two_way else "one-way"
    if floor:
        row["floor"] = floor.report()
    print(json.dumps(row, indent=2))
    write_json(args.output / f"optimize_{args.elements_x}_{args.backend}_{row['coupling']}.json", row)
    if profiler:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(int(__import__("os").environ.get("PROFILE_LINES", 15)))


if __name__ == "__main__":
    main()
