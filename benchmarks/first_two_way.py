"""What a two-way stage's first solve costs against a warm two-way evaluation (issue 32, item 2).

The large scene (``beam_in_channel_optimization_large``, a mesh of ``--elements-x`` by half as
many) through its three one-way stages (small strain, no mesh motion); then, in one process:

* ``first`` -- the first two-way stage's solve and adjoint at that design, from the one-way
  stages' state (finite strain, Yeoh mover, monolithic Newton; where the full inflow fails from
  there, the inflow ramp of :mod:`tofsi.coupling.load_ramp`);
* ``warm`` -- ``--warm`` evaluations (solve and adjoint) of designs perturbed by 1e-2 (normal,
  clipped to [0, 1]), each from the last two-way state, as an optimizer's next iterations.

With ``--after-one-way`` the process first evaluates the design at the last one-way stage from
its state (untimed), as the optimizer does before its first two-way stage in the same process:
what the two stages share (the flow's assembly pattern, ordering and LU analysis) is then built,
and ``first`` holds only what the two-way stage adds (without it, ``first`` also pays those, about
0.15 s at 80 x 40).

Process CPU seconds; the target (issue 32): ``first / median(warm)`` at most 3. The one-way
stages' design and state are kept in ``--cache`` (an ``.npz`` per mesh), so that the code of
two branches can be timed from the same start, alternately (``PYTHONPATH`` picks the code).

    python -m benchmarks.first_two_way --elements-x 80
    python -m benchmarks.first_two_way --elements-x 160 --warm 3 --cache /tmp/first
    python -m benchmarks.first_two_way --elements-x 80 --after-one-way
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

import tofsi
from tofsi.core.blocks import State
from tofsi.coupling.coupled import continuation
from tofsi.optimization.optimize import Optimizer

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization_large.toml"


def one_way_start(nx: int, cache: Path):
    """``(gamma, state)``: the design the three one-way stages reach and its one-way state (cached)."""
    path = cache / f"one_way_{nx}.npz"
    if path.exists():
        with np.load(path) as npz:
            fields = {name: npz[name] for name in ("w", "u")}
            return npz["gamma"], State(npz["rho"], {**fields, "x": None})
    problem = tofsi.Problem(load(nx))
    with tempfile.TemporaryDirectory() as tmp:
        gamma = Optimizer(problem, tmp).design_after(3)
    state = problem.solve(gamma)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, gamma=gamma, rho=state.rho, w=state.w, u=state.u)
    return gamma, state.data()


def load(nx: int):
    h = 2.0 / nx
    return tofsi.load_scene(SCENE, [f"mesh.h_min={h!r}", f"mesh.h_max={h!r}"])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements-x", type=int, default=80)
    ap.add_argument("--warm", type=int, default=3, help="warm evaluations after the first")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "tofsi_first_two_way")
    ap.add_argument("--after-one-way", action="store_true",
                    help="evaluate the design at the last one-way stage first, in this process (untimed)")
    args = ap.parse_args(argv)
    gamma, guess = one_way_start(args.elements_x, args.cache)
    problem = tofsi.Problem(load(args.elements_x))
    if args.after_one_way:
        problem.set_stage(continuation(problem.scene, 2))
        problem.set_guess(guess)
        problem.evaluate(gamma)
    problem.set_stage(continuation(problem.scene, 3))
    problem.set_guess(guess)
    t0 = time.process_time()
    f, g = problem.evaluate(gamma)
    first = time.process_time() - t0
    report = problem.point(gamma).state.reports
    rng = np.random.default_rng(0)
    warm = []
    for _ in range(args.warm):
        trial = np.clip(gamma + 1e-2 * rng.standard_normal(gamma.size), 0.0, 1.0)
        t0 = time.process_time()
        problem.evaluate(trial)
        warm.append(time.process_time() - t0)
    out = {"elements_x": args.elements_x, "after_one_way": args.after_one_way, "first_cpu_s": first, "warm_cpu_s": warm,
           "ratio": first / float(np.median(warm)) if warm else None, "objective": f,
           "gradient_norm": float(np.linalg.norm(g)), "ramp": report.get("load_ramp", {}).get("steps"),
           "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
           "load": os.getloadavg()[0]}
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
