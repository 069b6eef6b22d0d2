"""Resident memory per design iteration of the large scene with a mover in increments (issue 32).

Runs the large-deformation scene's one-way stages and then ``--iterations``
design iterations of its first two-way stage, and prints after each two-way
iteration the process's resident set, its high-water mark, the iteration's
CPU seconds and how many moves' derivative stores
(:class:`movers.incremental.IncrementDerivatives`) are alive -- without
collecting garbage first, so a store left to Python's cyclic collector shows:

    python benchmarks/spring_memory.py [--elements-x 40] [--iterations 20] [--set KEY=VALUE ...]

The defaults run the spring analogy in 10 increments (``--set mover.name=yeoh`` for the Yeoh
mover). Before the fix of 2026-11-27 the stores alive grew by one or two per iteration at
80 x 40 (6 to 16 over six iterations, 2.0 to 3.9 GB); since, two stay alive.
"""

from __future__ import annotations

import argparse
import gc
import resource
import tempfile
import time
from pathlib import Path

LARGE_SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization_large.toml"
ONE_WAY_STAGES = 3


def resident_gb() -> float:
    return int(Path("/proc/self/statm").read_text().split()[1]) * resource.getpagesize() / 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=40)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()

    import tofsi
    from tofsi.optimization.optimize import Optimizer

    h = 2.0 / args.elements_x
    sets = [f"mesh.h_min={h}", f"mesh.h_max={h}", "solver.linear_solver=superlu", "solver.blas_threads=1",
            "mover.name=spring", "mover.spring.increments=10", *args.set]
    scene = tofsi.load_scene(LARGE_SCENE, sets)
    iterations = ONE_WAY_STAGES * scene.design.stage_iterations + args.iterations
    problem = tofsi.Problem(tofsi.load_scene(LARGE_SCENE, sets + [f"optimizer.max_iter={iterations}"]))
    clock = [time.process_time()]
    print("two-way iteration, resident GB, peak GB, CPU s, stores alive")

    def on_iteration(it):
        if it.coupling == "two-way":
            stores = sum(type(o).__name__ == "IncrementDerivatives" for o in gc.get_objects())
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
            print(f"{it.iteration:4d} {resident_gb():7.3f} {peak:7.3f} {time.process_time() - clock[0]:7.2f} {stores:4d}",
                  flush=True)
        clock[0] = time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        Optimizer(problem, tmp, on_iteration=on_iteration).design_after(ONE_WAY_STAGES + 1)


if __name__ == "__main__":
    main()
