"""topFlow's and TOFLUX's published problems with the publishers' settings, and each difference
to tofsi's own choices measured on its own: element type, optimizer, settings.

Every problem is a shipped scene with the publisher's settings (``examples/scenes/topflow_*``,
``toflux_wall_in_channel``). Its variants change one thing at a time:

* topFlow (pipe bend, double pipes): ``q1q1-oc`` (the scene: Q1/Q1, optimality criteria),
  ``q2q1-oc`` (the element), ``q2q1-mma`` (the optimizer: NLopt's MMA, every q step its 50
  iterations), ``q2q1-mma-tofsi`` (tofsi's settings: a traction-free outlet whose end nodes
  are the wall's; for the double pipes also the fluid density 1, as the earlier shipped
  scenes) and ``q1q1-mma``; the rugby ball: ``q1q1-oc``, ``q2q1-oc`` and both at the fluid bound 0.99;
* TOFLUX (wall in a channel): ``q1q1-pressure`` (the scene: TOFLUX's element and load),
  ``q2q1-reaction`` (tofsi's defaults), ``q2q1-pressure``, ``q1q1-reaction``.

``run`` optimizes the variants (a finished run in the output folder is reused; run them one
at a time on a shared machine); ``report`` prints the tables of docs/optimization.md: each
final design's objective, non-discreteness and thresholded (0/1) objective, and for TOFLUX
every thresholded design scored by every model; ``--pictures DIR`` draws the designs side by
side.

    python -m benchmarks.published run [--problems NAME ...] [--output results/published]
    python -m benchmarks.published report [--output results/published] [--pictures DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "examples" / "scenes"

Q2 = "fluid.element=q2q1"
# MMA as tofsi runs it: every q step its 50 iterations (MMA's first steps after a change of q
# are small, and topFlow's rule -- five small changes in a row -- would end the step there)
MMA = ["optimizer.algorithm=MMA", "optimizer.tol_objective=1e-9"]
TOFSI_OUTLET = "fluid.outlet=traction-free"
TOPFLOW = {"q1q1-oc": [], "q2q1-oc": [Q2], "q2q1-mma": [Q2, *MMA], "q2q1-mma-tofsi": [Q2, *MMA, TOFSI_OUTLET],
           "q1q1-mma": MMA}
DOUBLE = {**TOPFLOW, "q2q1-mma-tofsi": [Q2, *MMA, TOFSI_OUTLET, "fluid.density=1.0", "optimizer.stall_iterations=3"]}
# problem: (scene, published value, published iterations, variants)
PROBLEMS = {
    "pipe bend": ("topflow_pipe_bend", 9.1862, 66, TOPFLOW),
    "double pipe": ("topflow_double_pipe", 22.0956, 63, DOUBLE),
    "double pipe, length 1.5": ("topflow_double_pipe_long", 23.5732, 87, DOUBLE),
    "rugby ball": ("topflow_rugby_ball", 13.503, 19, {"q1q1-oc": [], "q2q1-oc": [Q2]}),
    "rugby ball, 0.99": ("topflow_rugby_ball", 9.839, 17, {"q1q1-oc": ["design.volume_fraction=0.99"],
                                                          "q2q1-oc": ["design.volume_fraction=0.99", Q2]}),
    "TOFLUX wall": ("toflux_wall_in_channel", None, 300,
                    {"q1q1-pressure": [], "q2q1-reaction": [Q2, "structure.load=reaction"],
                     "q2q1-pressure": [Q2], "q1q1-reaction": ["structure.load=reaction"]}),
}


LABELS = {"q1q1-oc": "Q1/Q1, OC (the publisher's)", "q2q1-oc": "Q2/Q1, OC", "q2q1-mma": "Q2/Q1, MMA",
          "q2q1-mma-tofsi": "Q2/Q1, MMA, tofsi's settings", "q1q1-mma": "Q1/Q1, MMA",
          "q1q1-pressure": "Q1/Q1, pressure load (TOFLUX's)", "q2q1-reaction": "Q2/Q1, reaction load (tofsi's)",
          "q2q1-pressure": "Q2/Q1, pressure load", "q1q1-reaction": "Q1/Q1, reaction load"}


def folder(output: Path, problem: str, variant: str) -> Path:
    return output / problem.replace(" ", "_").replace(",", "") / variant


def run(problem: str, variant: str, output: Path) -> dict:
    """``tofsi optimize`` of one variant (reused when its folder holds a finished run)."""
    scene, _, _, variants = PROBLEMS[problem]
    out = folder(output, problem, variant)
    if not (out / "result.json").is_file():
        args = [sys.executable, "-m", "tofsi.cli", "optimize", str(SCENES / f"{scene}.toml"), "--output", str(out),
                "--overwrite", "-q"] + [a for o in variants[variant] for a in ("--set", o)]
        subprocess.run(args, check=True)
    return json.loads((out / "result.json").read_text())


def final_problem(problem: str, variant: str):
    """The variant's design problem at its last continuation stage."""
    import tofsi
    from tofsi.coupling.coupled import continuation
    scene_name, _, _, variants = PROBLEMS[problem]
    scene = tofsi.load_scene(SCENES / f"{scene_name}.toml", variants[variant])
    p = tofsi.Problem(scene)
    p.set_stage(continuation(scene, scene.design.n_stages - 1))
    return p


def sharp_densities(p, gamma) -> np.ndarray:
    """The design made 0/1: fluid problems at their fluid bound (the most fluid elements fluid),
    structural ones at rho = 1/2; fixed regions as they are."""
    rho = p.densities(gamma)
    d = p.map.design
    sharp = rho.copy()
    if p.scene.design.constraint == "fluid":
        n_fluid = int(round(p.scene.design.volume_fraction * d.size))
        values = np.ones(d.size)
        values[np.argsort(rho[d], kind="stable")[:n_fluid]] = 0.0
        sharp[d] = values
    else:
        sharp[d] = (rho[d] > 0.5).astype(float)
    return sharp


def objective_of(p, rho) -> float:
    """The problem's objective at fixed densities (no design map: a 0/1 design stays 0/1)."""
    state = p.model.solve(rho)
    return float(p.objective.value(p.model, state))


def analyse(problem: str, variant: str, output: Path) -> dict | None:
    """A finished run's figures (None when the variant has not been run)."""
    from tofsi.optimization.optimize import non_discreteness
    path = folder(output, problem, variant) / "result.json"
    if not path.is_file():
        return None
    result = json.loads(path.read_text())
    p = final_problem(problem, variant)
    gamma = np.load(folder(output, problem, variant) / "design.npy")
    rho = p.densities(gamma)
    _, published, _, _ = PROBLEMS[problem]
    return {"problem": problem, "variant": variant, "objective": result["objective"],
            "vs_published_percent": 100 * (result["objective"] / published - 1) if published else float("nan"),
            "non_discreteness_percent": non_discreteness(rho[p.map.design]),
            "thresholded": objective_of(p, sharp_densities(p, gamma)), "iterations": result["iterations"],
            "wall_time_s": result["wall_time_s"]}


def cross_scores(problem: str, output: Path, variants) -> list[dict]:
    """Every finished variant's thresholded design scored by every finished variant's model."""
    rows = []
    for design in variants:
        gamma = np.load(folder(output, problem, design) / "design.npy")
        sharp = sharp_densities(final_problem(problem, design), gamma)
        rows.append({"design": design, **{model: objective_of(final_problem(problem, model), sharp)
                                          for model in variants}})
    return rows


def pictures(problem: str, variants, output: Path, out: Path) -> Path:
    """The variants' designs side by side (black: solid), one panel each."""
    from tofsi.runs.plotting import plt, save
    fig, axes = plt.subplots(1, len(variants), figsize=(3.3 * len(variants), 3.4), dpi=100, squeeze=False)
    for ax, variant in zip(axes[0], variants, strict=True):
        p = final_problem(problem, variant)
        rho = p.densities(np.load(folder(output, problem, variant) / "design.npy"))
        m = p.model.mesh
        ax.pcolormesh(m.xs, m.ys, rho.reshape(m.ny, m.nx), cmap="Greys", vmin=0, vmax=1, shading="flat")
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        f = json.loads((folder(output, problem, variant) / "result.json").read_text())["objective"]
        symbol = "phi" if p.objective.name.startswith("dissipation") else p.objective.name
        ax.set_title(f"{LABELS[variant]}\n{symbol} = {f:.5g}", fontsize=8)
    path = out / f"{problem.replace(' ', '_').replace(',', '')}.png"
    save(fig, path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=("run", "report"))
    parser.add_argument("--problems", nargs="*", default=list(PROBLEMS), choices=list(PROBLEMS))
    parser.add_argument("--output", type=Path, default=Path("results/published"))
    parser.add_argument("--pictures", type=Path, help="draw the designs side by side here")
    args = parser.parse_args()
    for problem in args.problems:
        variants = PROBLEMS[problem][3]
        if args.command == "run":
            for variant in variants:
                run(problem, variant, args.output)
            continue
        rows = [r for r in (analyse(problem, v, args.output) for v in variants) if r is not None]
        print(f"\n{problem} (published {PROBLEMS[problem][1]}, {PROBLEMS[problem][2]} iterations)")
        print("| variant | objective | vs published | grey | thresholded | iterations | time |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            vs = "-" if np.isnan(r["vs_published_percent"]) else f"{r['vs_published_percent']:+.2f} %"
            print(f"| {r['variant']} | {r['objective']:.5g} | {vs} | {r['non_discreteness_percent']:.1f} % | "
                  f"{r['thresholded']:.5g} | {r['iterations']} | {r['wall_time_s']:.0f} s |")
        done = [r["variant"] for r in rows]
        if problem == "TOFLUX wall" and len(rows) > 1:
            print("\nthresholded designs (rows) scored by each model (columns)")
            print("| design | " + " | ".join(done) + " |\n|---|" + "---|" * len(done))
            for r in cross_scores(problem, args.output, done):
                print("| " + " | ".join([r["design"]] + [f"{r[v]:.5g}" for v in done]) + " |")
        if args.pictures and rows:
            print("picture:", pictures(problem, done, args.output, args.pictures))


if __name__ == "__main__":
    main()
