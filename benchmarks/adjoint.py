"""What the adjoint costs next to the forward solve and next to finite differences.

For the beam-in-channel optimization scene at several mesh sizes (one-way,
Navier-Stokes; and a soft two-way scene with the Yeoh mover) the script times

* ``forward``  -- the coupled solve of a design warm-started from a nearby
  design (as inside an optimization), and ``cold`` from scratch;
* ``adjoint``  -- the gradients of the objective and of the volume constraint
  together (one adjoint solve; the volume needs none), including the blocks;
* ``blocks``   -- assembling every partial-derivative block, against one forward
  residual-and-Jacobian assembly (``assembly``);
* ``FD/var``   -- a finite-difference gradient's cost per design variable (one
  warm forward solve; central differences need two).

and prints the ratios the project's targets are stated in: adjoint/forward
<= 0.25 and blocks/assembly <= 1. Each size runs in a fresh process.

    python benchmarks/adjoint.py
    python benchmarks/adjoint.py --sizes 0.05 0.025 --repeat 1
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

# This file is named like the ``adjoint`` package (and its folder holds ``movers.py``);
# running it as a script puts its folder first on sys.path, which would shadow both.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization.toml"
SIZES = [0.05, 0.025, 0.0167, 0.0111]            # ~800 .. 16 000 elements (180 x 90)
TWO_WAY = ["effects.coupling=two-way", "mover.name=yeoh", "structure.youngs_modulus=5e4",
           "structure.load_exponent=3", "coupled.method=monolithic"]


def run_case(h: float, two_way: bool) -> dict:
    import numpy as np

    import tofsi
    from adjoint import Adjoint

    overrides = [f"mesh.h_min={h}", f"mesh.h_max={h}"] + (TWO_WAY if two_way else [])
    problem = tofsi.Problem(tofsi.load_scene(SCENE, overrides))
    rng = np.random.default_rng(0)
    gamma = problem.initial_design() + 0.05 * rng.uniform(-1, 1, problem.n_design)
    t0 = time.perf_counter()
    problem.solve(gamma)
    cold = time.perf_counter() - t0
    gamma2 = gamma + 0.01 * rng.uniform(-1, 1, problem.n_design)     # the next design iterate
    t0 = time.perf_counter()
    state = problem.solve(gamma2)
    forward = time.perf_counter() - t0
    model, X = problem.model, state.mesh_displacement
    t0 = time.perf_counter()
    for block in model.system.blocks:           # every partial block as a sparse matrix
        lin = state.linearizations[block.name]
        for other in block.inputs:
            lin.coupling(other)
        lin.density()
    blocks = time.perf_counter() - t0
    t0 = time.perf_counter()
    model.flow.jacobian(state.w, X, state.rho, params=state.params)
    if model.structure is not None:
        model.structure.stiffness(state.rho, state.params)
    assembly = time.perf_counter() - t0
    t0 = time.perf_counter()
    problem.evaluate(gamma2)
    problem.constraints(gamma2)
    adjoint = time.perf_counter() - t0
    method = Adjoint(model.system, state).method()
    return {"elements": model.mesh.n_elements, "design_variables": problem.n_design,
            "dofs": model.flow.size + (2 * model.structure.size if two_way else model.structure.size),
            "cold_s": cold, "forward_s": forward, "adjoint_s": adjoint, "blocks_s": blocks,
            "assembly_s": assembly, "fd_per_variable_s": forward, "method": method,
            "fd_gradient_s": forward * problem.n_design}


def measure(h, two_way, repeat):
    best = None
    for _ in range(repeat):
        cmd = [sys.executable, __file__, "--one", str(h)] + (["--two-way"] if two_way else [])
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            raise RuntimeError(run.stderr)
        res = json.loads(run.stdout)
        if best is None or res["forward_s"] + res["adjoint_s"] < best["forward_s"] + best["adjoint_s"]:
            best = res
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=SIZES)
    parser.add_argument("--two-way-sizes", type=float, nargs="*", default=[0.05, 0.025])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks"))
    parser.add_argument("--one", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--two-way", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_case(args.one, args.two_way)))
        return
    from tofsi.output import write_json
    print(f"machine: {platform.machine()}, Python {platform.python_version()}")
    print(f"{'coupling':9s} {'elements':>8s} {'cold':>7s} {'forward':>8s} {'adjoint':>8s} {'adj/fwd':>8s}"
          f" {'blocks':>7s} {'assembly':>8s} {'blk/asm':>8s} {'FD/var':>7s} {'FD grad':>9s}")
    rows = []
    for two_way, sizes in ((False, args.sizes), (True, args.two_way_sizes)):
        for h in sizes:
            r = measure(h, two_way, args.repeat)
            r["coupling"] = "two-way" if two_way else "one-way"
            rows.append(r)
            print(f"{r['coupling']:9s} {r['elements']:8d} {r['cold_s']:7.2f} {r['forward_s']:8.2f} "
                  f"{r['adjoint_s']:8.3f} {r['adjoint_s'] / r['forward_s']:8.3f} {r['blocks_s']:7.3f} "
                  f"{r['assembly_s']:8.3f} {r['blocks_s'] / r['assembly_s']:8.2f} {r['forward_s']:7.2f} "
                  f"{r['fd_gradient_s']:9.0f}", flush=True)
    write_json(args.output / "adjoint.json", rows)
    print(f"wrote {args.output / 'adjoint.json'}")


if __name__ == "__main__":
    main()
