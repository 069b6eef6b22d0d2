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
its floor": at most 1.5 one-way). Times are process CPU seconds (the machine
is shared).

``--large`` runs the large-deformation scene (``beam_in_channel_optimization_large``)
through its three one-way stages and then ``--iterations`` design iterations
of its first two-way stage (beta 8, finite strain; issue 32), and reports what
that stage costs: the first two-way iteration (the stage's first two-way solve
from the one-way state, its adjoint and MMA), the warm two-way iterations
after it (median; with ``--floor``, their pieces and their time over their
factorizations), the warm one-way iterations of the last one-way stage
(median), and the ratios issue 32 sets targets for: warm two-way / its
factorizations, first two-way / warm two-way, warm two-way / warm one-way.

``--schedule`` runs the large scene's whole schedule (every stage, as ``tofsi
optimize`` does, at ``--elements-x``) and reports per stage its design
iterations, CPU and wall time, peak memory (the resident set's high-water
mark, reset at each stage's start), fallbacks and inflow ramps, and the final
figures (issue 32's research resolution: 160 x 80 and 320 x 160):

    python benchmarks/optimize.py [--elements-x 180] [--iterations 6] [--backend superlu]
                                  [--blas-threads 1] [--floor] [--large | --schedule]
                                  [--set KEY=VALUE ...]

``--set`` overrides scene values as ``tofsi``'s option does (e.g. ``--large --set
mover.name=spring``: the large scene with the spring analogy in the scene's increments, 3
midpoint ones, the first 0.1 of the motion).
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
LARGE_SCENE = SCENES / "beam_in_channel_optimization_large.toml"
ONE_WAY_STAGES = 3                  # the large scene's one-way stages before its first two-way one


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

    def report(self, first: int = 1, blocks=()) -> dict:
        """Per iteration between the marks ``first`` and the last (the iteration before mark
        ``first``, the first one measured, left out). ``blocks``: the sizes of the systems one
        iteration factorizes at least once when it builds its factors afresh (the two-way
        Newton's diagonal blocks): the iteration's time over one factorization of each (each
        at its mean time over the whole run), the floor issue 32 sets, also where the
        iterations factorize less (factors carried from the previous design)."""
        (t0, c0, s0), (t1, c1, s1) = self.marks[first], self.marks[-1]
        n = len(self.marks) - 1 - first
        rows = {k: {"per_iteration": (c1[k] - c0.get(k, 0)) / n, "seconds": (s1[k] - s0.get(k, 0)) / n}
                for k in sorted(c1)}
        factorizations = sum(r["seconds"] for k, r in rows.items() if k.startswith("factorization"))
        per_iteration = (t1 - t0) / n
        out = {"seconds_per_iteration": per_iteration, "factorization_s": factorizations,
               "iteration_over_factorizations": per_iteration / factorizations if factorizations else float("inf"),
               "pieces": rows}
        if blocks:
            each = sum(s1[f"factorization, {n} unknowns"] / c1[f"factorization, {n} unknowns"] for n in blocks)
            out.update({"one_factorization_each_s": each, "iteration_over_one_factorization_each": per_iteration / each})
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=180)
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--backend", default="superlu", help="solver.linear_solver (superlu, pardiso, auto, ...)")
    parser.add_argument("--blas-threads", type=int, default=1, help="solver.blas_threads (0: library default)")
    parser.add_argument("--profile", action="store_true", help="print where the time goes")
    parser.add_argument("--floor", action="store_true", help="count kernel passes, factorizations, solves")
    parser.add_argument("--large", action="store_true",
                        help="the large-deformation scene: its one-way stages, then --iterations two-way ones")
    parser.add_argument("--schedule", action="store_true",
                        help="the large-deformation scene's whole schedule, per stage: time and peak memory")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene value (as tofsi's --set), e.g. --set mover.name=spring")
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks"))
    args = parser.parse_args()

    import tofsi
    from tofsi.optimization.optimize import Optimizer
    from tofsi.runs.output import write_json

    h = 2.0 / args.elements_x
    sets = [f"mesh.h_min={h}", f"mesh.h_max={h}", f"solver.linear_solver={args.backend}",
            f"solver.blas_threads={args.blas_threads}", *args.set]
    if args.schedule:
        return schedule(tofsi.load_scene(LARGE_SCENE, sets), args, write_json)
    if args.large:
        scene = tofsi.load_scene(LARGE_SCENE, sets)
        scene = tofsi.load_scene(LARGE_SCENE, sets + [f"optimizer.max_iter="
                                                     f"{ONE_WAY_STAGES * scene.design.stage_iterations + args.iterations}"])
        return large(scene, args, write_json)
    sets += [f"optimizer.max_iter={args.iterations}", f"design.stage_iterations={args.iterations}"]
    scene = tofsi.load_scene(SCENE, sets)
    problem = tofsi.Problem(scene)
    floor = FloorCounter() if args.floor else None
    if floor:
        floor.install(args.backend)
    times = {"forward": [], "adjoint": [], "forward_cpu": [], "adjoint_cpu": []}
    krylov = {"newton": [], "transposed": []}             # (CPU s, iterations) of each flow GMRES

    def timed(fn, key):
        def wrapper(*a, **k):
            t0, c0 = time.perf_counter(), time.process_time()
            out = fn(*a, **k)
            times[key].append(time.perf_counter() - t0)
            times[key + "_cpu"].append(time.process_time() - c0)
            return out
        return wrapper

    def counted(fn, key):
        def wrapper(*a, **k):
            c0 = time.process_time()
            x, its = fn(*a, **k)
            krylov[key].append((time.process_time() - c0, its))
            return x, its
        return wrapper
    if args.backend == "iterative":               # the Newton steps' GMRES and the adjoint's transposed one
        import tofsi.linalg.iterative as iterative_module
        import tofsi.linalg.recycling as recycling_module
        recycling_module.gmres = counted(recycling_module.gmres, "newton")
        iterative_module.gmres = counted(iterative_module.gmres, "transposed")

    import adjoint.solve
    problem.model.solve = timed(problem.model.solve, "forward")
    adjoint.solve.Adjoint.gradient = timed(adjoint.solve.Adjoint.gradient, "adjoint")
    stamps, cpu_stamps = [], []
    with tempfile.TemporaryDirectory() as tmp:
        def on_iteration(it):
            stamps.append(time.perf_counter())
            cpu_stamps.append((time.process_time(), {k: len(v) for k, v in krylov.items()}))
            if floor:
                floor.mark()
        optimizer = Optimizer(problem, tmp, on_iteration=on_iteration)
        profiler = cProfile.Profile() if args.profile else None
        if profiler:
            profiler.enable()
        optimizer.run()
        if profiler:
            profiler.disable()
    per_iteration = [b - a for a, b in zip(stamps[:-1], stamps[1:], strict=True)]
    n = len(per_iteration)
    mean = lambda xs: sum(xs) / max(len(xs), 1)
    row = {"elements": problem.model.mesh.n_elements, "design_variables": problem.n_design,
           "flow_dofs": problem.model.flow.size, "iterations": len(stamps),
           "seconds_per_iteration": mean(per_iteration[1:]),
           "forward_s": mean(times["forward"][2:2 + n]),
           "adjoint_s": mean([a + b for a, b in zip(times["adjoint"][2::2], times["adjoint"][3::2], strict=False)]),
           "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2,
           "backend": args.backend, "blas_threads": args.blas_threads,
           "machine": f"{platform.machine()}, Python {platform.python_version()}"}
    row["mma_and_rest_s"] = row["seconds_per_iteration"] - row["forward_s"] - row["adjoint_s"]
    cpu = [b[0] - a[0] for a, b in zip(cpu_stamps[:-1], cpu_stamps[1:], strict=True)]
    row["cpu_seconds_per_iteration"] = mean(cpu[1:])
    row["forward_cpu_s"] = mean(times["forward_cpu"][2:2 + n])
    row["adjoint_cpu_s"] = mean([a + b for a, b in zip(times["adjoint_cpu"][2::2], times["adjoint_cpu"][3::2], strict=False)])
    if args.backend == "iterative" and len(cpu_stamps) > 2:     # per warm iteration: the flow's Krylov solves
        per = []
        for (_, a), (_, b) in zip(cpu_stamps[1:-1], cpu_stamps[2:], strict=True):
            newton = krylov["newton"][a["newton"]:b["newton"]]
            transposed = krylov["transposed"][a["transposed"]:b["transposed"]]
            if newton and transposed:
                per.append((max(t for t, _ in newton), sum(t for t, _ in newton) / len(newton),
                            sum(t for t, _ in transposed), [i for _, i in newton], [i for _, i in transposed]))
        row["krylov"] = [{"newton_iterations": p[3], "transposed_iterations": p[4],
                          "transposed_over_largest_newton_solve": p[2] / p[0],
                          "transposed_over_mean_newton_solve": p[2] / p[1]} for p in per]
    row["coupling"] = "one-way"
    if floor:
        row["floor"] = floor.report()
    print(json.dumps(row, indent=2))
    write_json(args.output / f"optimize_{args.elements_x}_{args.backend}_{row['coupling']}.json", row)
    if profiler:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(int(__import__("os").environ.get("PROFILE_LINES", 15)))


def large(scene, args, write_json) -> None:
    """The large scene's one-way stages and ``args.iterations`` iterations of its first two-way stage."""
    import statistics
    import tofsi
    from tofsi.optimization.optimize import Optimizer

    problem = tofsi.Problem(scene)
    floor = FloorCounter() if args.floor else None
    if floor:
        floor.install(args.backend)
    rows = []
    profiler = cProfile.Profile(time.process_time) if args.profile else None   # warm two-way iterations, CPU
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        def on_iteration(it):
            rows.append((it.stage, it.coupling, time.process_time(), it.load_steps, it.fallbacks))
            if floor and it.coupling == "two-way":
                floor.mark()
            if profiler and it.coupling == "two-way":
                done = sum(r[1] == "two-way" for r in rows) >= args.iterations
                profiler.disable() if done else profiler.enable()
        Optimizer(problem, tmp, on_iteration=on_iteration).design_after(ONE_WAY_STAGES + 1)
    cpu = [b[2] - a[2] for a, b in zip([(0, "", t0)] + rows[:-1], rows, strict=True)]
    one_way = [c for c, r in zip(cpu, rows, strict=True) if r[0] == ONE_WAY_STAGES - 1][1:]
    two_way = [c for c, r in zip(cpu, rows, strict=True) if r[1] == "two-way"]
    first, warm = two_way[0], statistics.median(two_way[1:])
    row = {"scene": scene.name, "elements": problem.model.mesh.n_elements, "design_variables": problem.n_design,
           "flow_dofs": problem.model.flow.size, "two_way_iterations": len(two_way),
           "first_two_way_cpu_s": first, "first_two_way_ramp_steps": rows[len(rows) - len(two_way)][3],
           "warm_two_way_cpu_s": warm, "warm_two_way_cpu_s_all": two_way[1:],
           "warm_one_way_cpu_s": statistics.median(one_way), "fallbacks": rows[-1][4],
           "first_over_warm": first / warm, "two_way_over_one_way": warm / statistics.median(one_way),
           "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2,
           "backend": args.backend, "blas_threads": args.blas_threads,
           "machine": f"{platform.machine()}, Python {platform.python_version()}"}
    if floor:
        sizes = [b.size for b in problem.model.system_for(problem.stage).blocks]
        row["floor"] = floor.report(first=0, blocks=sizes)  # the warm two-way iterations
    print(json.dumps(row, indent=2))
    tag = "".join(f"_{s.replace('=', '-')}" for s in args.set)
    row["set"] = args.set
    write_json(args.output / f"optimize_large_{args.elements_x}_{args.backend}{tag}.json", row)
    if profiler:
        profiler.dump_stats(args.output / f"optimize_large_{args.elements_x}{tag}.prof")
        pstats.Stats(profiler).sort_stats("tottime").print_stats(int(__import__("os").environ.get("PROFILE_LINES", 15)))


def high_water_mark_gb(reset: bool = False) -> float:
    """The process's peak resident set so far [GB] (Linux ``VmHWM``); ``reset`` starts it again
    from the current resident set (``/proc/self/clear_refs``)."""
    status = Path("/proc/self/status").read_text()
    peak = int(next(line for line in status.splitlines() if line.startswith("VmHWM:")).split()[1]) / 1024**2
    if reset:
        Path("/proc/self/clear_refs").write_text("5")
    return peak


def schedule(scene, args, write_json) -> None:
    """The large scene's whole schedule, per stage: iterations, CPU and wall time, peak memory."""
    import tofsi
    from tofsi.optimization.optimize import Optimizer

    problem = tofsi.Problem(scene)
    stages: dict = {}
    clock = {"cpu": time.process_time(), "wall": time.perf_counter()}
    high_water_mark_gb(reset=True)

    def on_iteration(it):
        key = f"{it.stage} ({it.coupling}, beta {it.beta:g})"
        if key not in stages and stages:
            last = stages[next(reversed(stages))]
            last["peak_rss_gb"] = high_water_mark_gb(reset=True)       # (up to this stage's first iteration)
        row = stages.setdefault(key, {"iterations": 0, "cpu_s": 0.0, "wall_s": 0.0, "ramp_steps": 0})
        cpu, wall = time.process_time(), time.perf_counter()
        row["iterations"] += 1
        row["cpu_s"] += cpu - clock["cpu"]
        row["wall_s"] += wall - clock["wall"]
        row["ramp_steps"] += it.load_steps
        row["fallbacks_after"] = it.fallbacks
        clock.update(cpu=cpu, wall=wall)
        print(f"iteration {it.iteration:4d} stage {key}: {it.objective:.5g}, {cpu - clock.get('start', 0):.0f} s CPU",
              flush=True)
    clock["start"] = clock["cpu"]
    with tempfile.TemporaryDirectory() as tmp:
        result = Optimizer(problem, tmp, on_iteration=on_iteration).run()
    stages[next(reversed(stages))]["peak_rss_gb"] = high_water_mark_gb()
    row = {"scene": scene.name, "elements": problem.model.mesh.n_elements, "flow_dofs": problem.model.flow.size,
           "stages": stages, "total_cpu_s": time.process_time() - clock["start"],
           "peak_rss_gb": max(s["peak_rss_gb"] for s in stages.values()),   # (the reset clears ru_maxrss too)
           "result": {k: result[k] for k in ("objective", "volume", "iterations", "fallbacks", "stop_reason",
                                             "max_displacement", "min_skewness") if k in result},
           "backend": args.backend, "blas_threads": args.blas_threads,
           "machine": f"{platform.machine()}, Python {platform.python_version()}"}
    print(json.dumps(row, indent=2))
    write_json(args.output / f"schedule_large_{args.elements_x}_{args.backend}.json", row)


if __name__ == "__main__":
    main()
