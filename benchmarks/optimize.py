"""Time and memory of one design iteration on the 180 x 90 beam-in-channel problem.

One iteration = forward solve (Navier-Stokes flow, then the structure), the
adjoint gradients of the objective and of the volume constraint, and NLopt's
MMA update. The script runs a few iterations of the real driver (one-way
coupling, the scene's Reynolds number), reports the mean time per iteration
after the first and where it goes (forward / adjoint / rest), and the peak
memory. Target: at most 4 s per iteration and 4 GB on two cores.

    python benchmarks/optimize.py [--elements-x 180] [--iterations 6] [--backend superlu]
                                  [--blas-threads 1]
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


SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization.toml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=180)
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--backend", default="superlu", help="solver.linear_solver (superlu, pardiso, auto, ...)")
    parser.add_argument("--blas-threads", type=int, default=1, help="solver.blas_threads (0: library default)")
    parser.add_argument("--profile", action="store_true", help="print where the time goes")
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks"))
    args = parser.parse_args()

    import tofsi
    from tofsi.optimize import Optimizer
    from tofsi.output import write_json

    h = 2.0 / args.elements_x
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}",
                                     f"optimizer.max_iter={args.iterations}",
                                     f"design.stage_iterations={args.iterations}",
                                     f"solver.linear_solver={args.backend}",
                                     f"solver.blas_threads={args.blas_threads}"])
    problem = tofsi.Problem(scene)
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
        optimizer = Optimizer(problem, tmp, on_iteration=lambda it: stamps.append(time.perf_counter()))
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
    print(json.dumps(row, indent=2))
    write_json(args.output / f"optimize_{args.elements_x}_{args.backend}.json", row)
    if profiler:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()
