"""What the finite-strain (neo-Hookean) structure solve costs next to the linear one.

The headline scene (``beam_in_channel_optimization_fsi``: 80 x 40 = 3200 elements, E = 5 kPa,
Emin = 1e-4 E0, load rho^3), solved one-way at the benchmark design of ``adjoint_speed.py``
(a solid post around the wall, 16 % of the design region, with +-0.05 noise, projected at
beta 16). The flow is solved once; its load is the same for both models and is evaluated
before the clock starts. Timed, alternately in one process (ratios pair by pair):

* ``linear``  -- ``Structure.solve``: the stiffness assembled and factorized, one solve;
* ``neo-hookean`` -- ``Structure.solve`` with ``structure.model = "neo-hookean"`` (energy
  interpolation): Newton from zero (load steps, line search; the first step is the linear
  solve), at the full load and at fractions of it (``--fractions``);
* ``warm`` -- the neo-Hookean solve from the solution at 95 % of the load (as inside an
  optimization, warm-started from the previous design or coupling sweep).

The target (issue 22): the finite-strain solve at most 3x the linear one at 3200 elements.

    python -m benchmarks.finite_strain
    python -m benchmarks.finite_strain --repeat 9 --fractions 0.25 0.5 1
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "scenes" / "beam_in_channel_optimization_fsi.toml"
ONE_WAY = ["effects.coupling=one-way", "effects.mesh_motion=none", 'design.coupling=["one-way"]']


def benchmark_state(problem):
    """The flow state at the post design (beta 16), as in ``adjoint_speed.py``."""
    from benchmarks.adjoint_speed import post_design

    problem.set_stage(problem.stage.with_params(beta=16.0))
    return problem.solve(post_design(problem, np.random.default_rng(0)))


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main(argv=None) -> dict:
    import tofsi
    from tofsi.physics.structure import Structure

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="alternating pairs per row")
    parser.add_argument("--fractions", type=float, nargs="+", default=[0.25, 0.5, 1.0],
                        help="fractions of the flow load")
    parser.add_argument("--output", type=Path, default=ROOT / "results" / "benchmarks")
    args = parser.parse_args(argv)

    scene = tofsi.load_scene(SCENE, ONE_WAY)
    problem = tofsi.Problem(scene)
    model = problem.model
    state = benchmark_state(problem)
    linear = model.structure
    settings = dataclasses.replace(scene.structure, model="neo-hookean")
    finite = Structure(model.mesh, settings, model.flow, linear_algebra=model.linear_algebra)
    w, rho, params = state.w, state.rho, state.params
    f = linear.load(w, None, rho, params)
    assert np.array_equal(f, finite.load(w, None, rho, params))       # both loads kept, same values
    simp = linear.simp(params)
    height = float(np.ptp(model.mesh.points[:, 1]))
    rows = []
    with model.linear_algebra.blas():
        for fraction in args.fractions:
            load = fraction * f
            pairs = []
            for _ in range(args.repeat):
                t_lin, u_lin = timed(lambda load=load: linear.factorize(rho, params).solve(linear.bc.homogenize(load)))
                t_nh, sol = timed(lambda load=load: finite.material().elasticity.solve(load, rho, simp))
                pairs.append((t_lin, t_nh))
            t_lin, t_nh = np.median(np.array(pairs), axis=0)
            ratio = float(np.median([b / a for a, b in pairs]))
            near = finite.material().elasticity.solve(0.95 * load, rho, simp).u
            warm = [timed(lambda load=load, near=near: finite.material().elasticity.solve(load, rho, simp, guess=near)) for _ in range(args.repeat)]
            t_warm = float(np.median([t for t, _ in warm]))
            report = sol.report
            rows.append({"fraction": fraction,
                         "max_displacement_linear": float(np.abs(u_lin.reshape(-1, 2)).max()),
                         "max_displacement": float(np.linalg.norm(sol.u.reshape(-1, 2), axis=1).max()),
                         "of_height": float(np.linalg.norm(sol.u.reshape(-1, 2), axis=1).max() / height),
                         "newton_iterations": report.newton_iterations, "load_steps": report.load_steps,
                         "factorizations": report.factorizations,
                         "warm_newton_iterations": warm[-1][1].report.newton_iterations,
                         "linear_s": float(t_lin), "neo_hookean_s": float(t_nh), "warm_s": t_warm,
                         "ratio": ratio, "warm_ratio": t_warm / float(t_lin)})
    print(f"{model.mesh.n_elements} elements, load average {os.getloadavg()[0]:.2f}, "
          f"median of {args.repeat} alternating pairs")
    print(f"{'load':>5s} {'max u [m]':>9s} {'/ height':>8s} {'lin u':>7s} {'Newton':>6s} {'LU':>3s} "
          f"{'linear s':>9s} {'neo-Hk s':>9s} {'ratio':>6s} {'warm s':>7s} {'warm its':>8s} {'warm ratio':>10s}")
    for r in rows:
        print(f"{r['fraction']:5.2f} {r['max_displacement']:9.4f} {r['of_height']:8.3f} "
              f"{r['max_displacement_linear']:7.4f} {r['newton_iterations']:6d} {r['factorizations']:3d} "
              f"{r['linear_s']:9.4f} {r['neo_hookean_s']:9.4f} {r['ratio']:6.2f} {r['warm_s']:7.4f} "
              f"{r['warm_newton_iterations']:8d} {r['warm_ratio']:10.2f}")
    full = [r for r in rows if r["fraction"] == 1.0]
    if full:
        print(f"target: finite-strain / linear solve <= 3 at the full load: {full[0]['ratio']:.2f} "
              f"({'met' if full[0]['ratio'] <= 3 else 'not met'})")
    out = {"machine": platform.platform(), "load_average": os.getloadavg()[0], "rows": rows}
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "finite_strain.json").write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
