"""What the adjoint costs next to the forward solve and next to finite differences.

For the beam-in-channel optimization scene at several mesh sizes (one-way,
Navier-Stokes at a random design) and for the headline two-way scene
(``beam_in_channel_optimization_fsi``: Yeoh mover with density-grown layers,
E = 5 kPa, at its last stage, beta 16, for a solid post around the wall with a
little noise: a design the soft structure can hold) the script times

* ``forward``  -- the coupled solve of a design warm-started from a nearby
  design (as inside an optimization), and ``cold`` from scratch;
* ``adjoint``  -- the gradients of the objective and of the volume constraint
  together (one adjoint solve; the volume needs none), including the blocks they build;
* ``blocks``   -- assembling every partial-derivative block (on a fresh state), against
  one forward residual-and-Jacobian assembly (``assembly``);
* ``FD/var``   -- a finite-difference gradient's cost per design variable (one
  warm forward solve; central differences need two).

and prints the ratios the project's targets are stated in: adjoint/forward
<= 0.25 one-way and <= 0.3 two-way, blocks/assembly <= 1 one-way and <= 2
two-way (``assembly`` is then every field's residual and Jacobian: flow,
structure and mesh), and a two-way design iteration (forward + adjoint) /
the one-way iteration of the same scene, mesh and design <= 2.5. Each case
runs in a fresh process.

    python benchmarks/adjoint_speed.py
    python benchmarks/adjoint_speed.py --sizes 0.05 0.025 --two-way-sizes 0.025 --repeat 1
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import subprocess
import sys
import time
from pathlib import Path


SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization.toml"
SIZES = [0.05, 0.025, 0.0167, 0.0111]            # ~800 .. 16 000 elements (180 x 90)
FSI_SCENE = SCENE.with_name("beam_in_channel_optimization_fsi.toml")


def assembly_time(model, system, state) -> float:
    """One residual-and-Jacobian assembly of every field with a residual, from the element
    kernels (no kept evaluation reused): the flow's, the structure's, the mesh's."""
    from tofsi.fem.assembly import assemble_vector

    t0 = time.perf_counter()
    fl, X = model.flow, state.mesh_displacement
    Re, Ke = fl.element_residual(state.w, X, state.rho, params=state.params)
    fl.bc.matrix(Ke), assemble_vector(fl.dofs, Re, fl.size)
    if model.structure is not None:
        model.structure.stiffness(state.rho, state.params)
    for block in system.blocks:
        if block.name == "x" and block.has_residual:
            block.linearize(state.fields, state.rho, state.params).matrix()
    return time.perf_counter() - t0


def post_design(problem, rng):
    """A solid post x in [0.8, 1.2], y < 0.6 around the wall (16 % of the design region), void
    elsewhere, with +-0.05 noise: a design the soft two-way structure holds."""
    import numpy as np

    c = problem.model.mesh.centroids[problem.model.design_elements]
    post = (np.abs(c[:, 0] - 1.0) < 0.2) & (c[:, 1] < 0.6)
    gamma = np.where(post, 0.95, 0.05)
    return np.clip(gamma + 0.05 * rng.uniform(-1, 1, gamma.size), 0.0, 1.0)


def time_iteration(problem, gamma, rng) -> dict:
    """Times of one design iteration from ``gamma``: a cold solve, a warm solve of a nearby
    design and its adjoint (objective and volume gradients, building whatever blocks they
    need), then, on a third nearby design's fresh state, every partial block and one assembly."""
    import numpy as np

    from adjoint import Adjoint

    def nearby(g):
        return np.clip(g + 0.01 * rng.uniform(-1, 1, g.size), 0.0, 1.0)

    t0 = time.perf_counter()
    problem.solve(gamma)
    cold = time.perf_counter() - t0
    gamma2 = nearby(gamma)                     # the next design iterate
    t0 = time.perf_counter()
    state = problem.solve(gamma2)
    forward = time.perf_counter() - t0
    t0 = time.perf_counter()
    problem.evaluate(gamma2)
    problem.constraints(gamma2)
    adjoint = time.perf_counter() - t0
    system = problem.model.system_for(state.params)
    method = Adjoint(system, state).method()
    fresh = problem.solve(nearby(gamma2))     # blocks not yet built by any adjoint
    t0 = time.perf_counter()
    for block in system.blocks:                # every partial block as a sparse matrix
        lin = fresh.linearizations[block.name]
        for other in block.inputs:
            lin.coupling(other)
        lin.density()
    blocks = time.perf_counter() - t0
    assembly = assembly_time(problem.model, system, fresh)
    return {"elements": problem.model.mesh.n_elements, "design_variables": problem.n_design,
            "dofs": sum(b.size for b in system.blocks), "cold_s": cold, "forward_s": forward,
            "adjoint_s": adjoint, "blocks_s": blocks, "assembly_s": assembly,
            "fd_per_variable_s": forward, "method": method, "fd_gradient_s": forward * problem.n_design}


def run_fsi_case(h: float, coupling: str) -> dict:
    """The headline scene at its last stage (beta 16), one-way or two-way, at the post design."""
    import numpy as np

    import tofsi

    problem = tofsi.Problem(tofsi.load_scene(FSI_SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}"]))
    problem.set_stage(dataclasses.replace(problem.params, beta=problem.scene.design.beta[-1], coupling=coupling))
    rng = np.random.default_rng(0)
    return time_iteration(problem, post_design(problem, rng), rng)


def run_case(h: float) -> dict:
    """The one-way beam scene at a random design."""
    import numpy as np

    import tofsi

    problem = tofsi.Problem(tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}"]))
    rng = np.random.default_rng(0)
    gamma = np.clip(problem.initial_design() + 0.05 * rng.uniform(-1, 1, problem.n_design), 0.0, 1.0)
    return time_iteration(problem, gamma, rng)


def measure(case: list[str], repeat: int) -> dict:
    """The best of ``repeat`` fresh processes running ``--one`` with ``case``'s arguments."""
    best = None
    for _ in range(repeat):
        run = subprocess.run([sys.executable, __file__, "--one"] + case, capture_output=True, text=True)
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
    parser.add_argument("--one", nargs=2, help=argparse.SUPPRESS)      # case size
    args = parser.parse_args()
    if args.one:
        case, h = args.one[0], float(args.one[1])
        row = run_case(h) if case == "beam" else run_fsi_case(h, case)
        print(json.dumps(row))
        return
    from tofsi.runs.output import write_json
    print(f"machine: {platform.machine()}, Python {platform.python_version()}")
    print(f"{'scene':5s} {'coupling':9s} {'elements':>8s} {'cold':>7s} {'forward':>8s} {'adjoint':>8s}"
          f" {'adj/fwd':>8s} {'blocks':>7s} {'assembly':>8s} {'blk/asm':>8s} {'FD grad':>9s} {'2w/1w':>6s}")
    cases = [("beam", h) for h in args.sizes]
    cases += [(c, h) for h in args.two_way_sizes for c in ("one-way", "two-way")]
    rows, one_way = [], {}
    for case, h in cases:
        r = measure([case, str(h)], args.repeat)
        r["scene"] = "beam" if case == "beam" else "fsi"
        r["coupling"] = "one-way" if case == "beam" else case
        iteration = r["forward_s"] + r["adjoint_s"]
        ratio = ""
        if case == "one-way":
            one_way[h] = iteration
        elif case == "two-way":
            r["two_way_over_one_way"] = iteration / one_way[h]
            ratio = f"{r['two_way_over_one_way']:6.2f}"
        rows.append(r)
        print(f"{r['scene']:5s} {r['coupling']:9s} {r['elements']:8d} {r['cold_s']:7.2f} {r['forward_s']:8.2f} "
              f"{r['adjoint_s']:8.3f} {r['adjoint_s'] / r['forward_s']:8.3f} {r['blocks_s']:7.3f} "
              f"{r['assembly_s']:8.3f} {r['blocks_s'] / r['assembly_s']:8.2f} "
              f"{r['fd_gradient_s']:9.0f} {ratio:>6s}", flush=True)
    write_json(args.output / "adjoint.json", rows)
    print(f"wrote {args.output / 'adjoint.json'}")


if __name__ == "__main__":
    main()
