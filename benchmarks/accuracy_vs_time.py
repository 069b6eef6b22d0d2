"""What accuracy costs in time: Pareto plots for movers, flow, coupling and gradients.

Every setting's error is measured against a reference solution (the same
method on a finer setting) and plotted against its wall time, with the
recommended default marked. Studies:

* movers   -- increments, Newton tolerance, mesh size and linear solver, for
              each mover on the foil rotation (30 deg) and the beam;
* flow     -- drag and pressure drop versus time as the mesh is refined,
              Stokes and Navier-Stokes, on the beam in a channel;
* coupling -- partitioned versus monolithic two-way coupling versus tolerance;
* gradient -- adjoint versus finite differences (error and time per gradient).

``--docs`` writes ``docs/accuracy_vs_time.md`` and its figures (``docs/img/accuracy``);
otherwise results go to ``--output``. About 20 minutes on two cores:

    python benchmarks/accuracy_vs_time.py --docs
    python benchmarks/accuracy_vs_time.py --studies movers --quick
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

# This folder holds ``movers.py`` and ``adjoint.py``, named like the packages.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "examples" / "scenes"


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


# ---- movers ---------------------------------------------------------------------------
MOVER_PROBLEMS = {"foil rotation": ("foil_in_channel", ["deformation.mode=rotation"]),
                  "beam": ("beam_in_channel", [])}
MOVER_SETTINGS = {
    "spring": ("increments", [3, 5, 10, 20, 30, 60], 240, 30),
    "linear": ("increments", [1, 2, 5, 10, 20], 80, 1),
    "yeoh": ("newton_tol", [1e-3, 1e-4, 1e-6, 1e-8, 1e-10], 1e-13, 1e-10),
}


def move(problem, mover, extra):
    import tofsi
    from tofsi.errors import NumericalError
    from tofsi.motion import motion_setup, run_move
    scene_name, base = MOVER_PROBLEMS[problem]
    scene = tofsi.load_scene(SCENES / f"{scene_name}.toml", base + [f"mover.name={mover}"] + extra)
    setup = motion_setup(scene)
    t0 = time.perf_counter()
    try:
        _, result = run_move(scene, setup=setup)
        x, q = result.displacement, result.report.quality[-1]
    except NumericalError as err:
        x, q = err.state, err.diagnostic["quality"]
    return x, q["min_skewness"], time.perf_counter() - t0, setup.mesh.n_nodes


def mover_study(quick: bool) -> list[dict]:
    rows = []
    for problem in MOVER_PROBLEMS:
        for mover, (key, values, ref_value, default) in MOVER_SETTINGS.items():
            values = values[:3] if quick else values
            x_ref, skew_ref, t_ref, _ = move(problem, mover, [f"mover.{mover}.{key}={ref_value}"])
            for v in values:
                x, skew, t, n = move(problem, mover, [f"mover.{mover}.{key}={v}"])
                rows.append({"study": "parameter", "problem": problem, "mover": mover, "parameter": key,
                             "value": v, "time_s": t, "min_skewness": skew, "nodes": n,
                             "error": float(np.abs(x - x_ref).max() / np.abs(x_ref).max()),
                             "default": v == default, "reference_time_s": t_ref})
            for solver in ("direct", "amg"):
                x, skew, t, n = move(problem, mover, [f"mover.{mover}.linear_solver={solver}"])
                rows.append({"study": "solver", "problem": problem, "mover": mover, "parameter": "linear_solver",
                             "value": solver, "time_s": t, "min_skewness": skew, "nodes": n,
                             "error": float(np.abs(x - x_ref).max() / np.abs(x_ref).max()),
                             "default": solver == "direct"})
            refine = [1.0, 1.5] if quick else [0.75, 1.0, 1.5, 2.0]
            for r in refine:
                x, skew, t, n = move(problem, mover, [f"mesh.h_min={0.0125 / r}", f"mesh.h_max={0.05 / r}"])
                rows.append({"study": "mesh", "problem": problem, "mover": mover, "parameter": "refinement",
                             "value": r, "time_s": t, "min_skewness": skew, "nodes": n, "error": np.nan,
                             "default": r == 1.0})
    return rows


# ---- flow -----------------------------------------------------------------------------
def flow_study(quick: bool) -> list[dict]:
    import dataclasses

    import tofsi
    from tofsi.channel import build_mesh
    from tofsi.mesh import SOLID
    from tofsi.physics.flow import Flow
    from tofsi.physics.structure import Structure
    scene = tofsi.load_scene(SCENES / "beam_in_channel.toml")
    hs = [0.05, 0.025, 0.0125] if quick else [0.05, 0.035, 0.025, 0.0175, 0.0125, 0.00625]
    rows = []
    for model in ("stokes", "navier-stokes"):
        results = []
        for h in hs:
            s = dataclasses.replace(scene, mesh=dataclasses.replace(scene.mesh, h_min=h, h_max=4 * h))
            mesh = build_mesh(s.geometry, s.mesh)
            rho = (mesh.region == SOLID).astype(float)
            flow = Flow(mesh, dataclasses.replace(s.fluid, alpha_max=1e6), stokes=model == "stokes")
            (w, _), t = timed(flow.solve, None, rho)
            drag = Structure(mesh, s.structure, flow).figures(np.zeros(2 * mesh.n_nodes), w, None, rho)["drag"]
            results.append((h, mesh.n_elements, t, drag, flow.figures(w, rho=rho)["pressure_drop"]))
        _, _, _, drag_ref, dp_ref = results[-1]
        for h, n, t, drag, dp in results[:-1]:
            rows.append({"study": "flow", "model": model, "h_min": h, "elements": n, "time_s": t,
                         "drag": drag, "pressure_drop": dp, "drag_error": abs(drag / drag_ref - 1),
                         "pressure_drop_error": abs(dp / dp_ref - 1), "default": h == 0.0125})
    return rows


# ---- coupling -------------------------------------------------------------------------
def coupling_study(quick: bool) -> list[dict]:
    import tofsi
    from tofsi.coupled import CoupledModel
    base = ["mesh.h_min=0.05", "mesh.h_max=0.05", "effects.coupling=two-way", "mover.name=yeoh",
            "structure.youngs_modulus=5e5", "fluid.alpha_max=1e4"]

    def solve(method, tol):
        scene = tofsi.load_scene(SCENES / "beam_in_channel_optimization.toml",
                                 base + [f"coupled.method={method}", f"coupled.tol={tol}"])
        model = CoupledModel(scene)
        c = model.mesh.centroids[model.design_elements]
        rho = model.densities(((np.abs(c[:, 0] - 1.0) < 0.1) & (c[:, 1] < 0.6)).astype(float))
        state, t = timed(model.solve, rho)
        return state, t
    ref, _ = solve("monolithic", 1e-12)
    rows = []
    for method in ("partitioned", "monolithic"):
        for tol in ([1e-4, 1e-8] if quick else [1e-3, 1e-4, 1e-6, 1e-8, 1e-10]):
            state, t = solve(method, tol)
            rows.append({"study": "coupling", "method": method, "tol": tol, "time_s": t,
                         "error": float(np.abs(state.u - ref.u).max() / np.abs(ref.u).max()),
                         "default": method == "partitioned" and tol == 1e-9})
    return rows


# ---- gradient -------------------------------------------------------------------------
def gradient_study(quick: bool) -> list[dict]:
    import tofsi
    scene = tofsi.load_scene(SCENES / "beam_in_channel_optimization.toml",
                             ["mesh.h_min=0.05", "mesh.h_max=0.05", "fluid.newton_tol=1e-13"])
    P = tofsi.Problem(scene)
    rng = np.random.default_rng(0)
    gamma = rng.uniform(0.1, 0.9, P.n_design)
    P.solve(gamma)
    (f0, df), t_adj = timed(P.evaluate, gamma)
    _, t_fwd = timed(P.solve, gamma + 1e-3)
    sample = rng.choice(P.n_design, 4 if quick else 12, replace=False)
    rows = [{"study": "gradient", "method": "adjoint", "h": np.nan, "error": 0.0,
             "time_per_gradient_s": t_adj, "default": True}]
    for h in (1e-2, 1e-4, 1e-6, 1e-8):
        errs, t_total = [], 0.0
        for i in sample:
            e = np.zeros(P.n_design)
            e[i] = h
            (fp, _), t = timed(P.evaluate, gamma + e)
            t_total += t
            errs.append(abs((fp - f0) / h - df[i]) / max(abs(df).max(), 1e-300))
        rows.append({"study": "gradient", "method": "forward differences", "h": h, "error": float(np.max(errs)),
                     "time_per_gradient_s": t_total / len(sample) * P.n_design, "default": False})
    for r in rows:
        r["forward_solve_s"] = t_fwd
        r["design_variables"] = P.n_design
    return rows


# ---- report ---------------------------------------------------------------------------
def pareto(ax, rows, x, y, label_key, title):
    from itertools import groupby
    rows = sorted(rows, key=lambda r: str(r[label_key]))
    for label, group in groupby(rows, key=lambda r: str(r[label_key])):
        g = sorted(group, key=lambda r: r[x])
        ax.plot([r[x] for r in g], [max(r[y], 1e-16) for r in g], "o-", ms=4, label=label)
        for r in g:
            if r.get("default"):
                ax.plot(r[x], max(r[y], 1e-16), "r*", ms=14, zorder=5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(x.replace("_", " "))
    ax.set_ylabel(y.replace("_", " "))
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)


def report(results: dict, out: Path, docs: bool) -> None:
    from tofsi.output import write_csv, write_text
    from tofsi.plotting import plt, save
    img = out / ("img/accuracy" if docs else "")
    for name, rows in results.items():
        write_csv((out / "img/accuracy" if docs else out) / f"{name}.csv", rows)
    lines = ["# What accuracy costs in time", "",
             f"Measured by `benchmarks/accuracy_vs_time.py` on {platform.machine()} "
             f"(2 cores, Python {platform.python_version()}); regenerate with "
             "`python benchmarks/accuracy_vs_time.py --docs`. Every error is against a reference "
             "solution of the same method on a finer setting; red stars mark the recommended defaults.", ""]
    if "movers" in results:
        rows = results["movers"]
        for problem in MOVER_PROBLEMS:
            fig, axes = plt.subplots(1, 3, figsize=(14, 3.8), dpi=100)
            for ax, mover in zip(axes, MOVER_SETTINGS):
                sel = [r for r in rows if r["problem"] == problem and r["mover"] == mover and r["study"] == "parameter"]
                pareto(ax, sel, "time_s", "error", "parameter", f"{mover}: {sel[0]['parameter']}")
            save(fig, img / f"movers_{problem.replace(' ', '_')}.png")
            lines += [f"## Movers: {problem}", "",
                      f"![movers {problem}](img/accuracy/movers_{problem.replace(' ', '_')}.png)", "",
                      "| mover | setting | value | time [s] | error vs reference | min skewness |",
                      "|---|---|---|---|---|---|"]
            for r in [r for r in rows if r["problem"] == problem]:
                star = " (default)" if r["default"] else ""
                lines.append(f"| {r['mover']} | {r['parameter']} | {r['value']}{star} | {r['time_s']:.2f} | "
                             f"{r['error']:.2e} | {r['min_skewness']:.4f} |")
            lines.append("")
    if "flow" in results:
        rows = results["flow"]
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), dpi=100)
        pareto(axes[0], rows, "time_s", "drag_error", "model", "drag error vs time (mesh refinement)")
        pareto(axes[1], rows, "time_s", "pressure_drop_error", "model", "pressure-drop error vs time")
        save(fig, img / "flow.png")
        lines += ["## Flow: mesh refinement, Stokes and Navier-Stokes", "", "![flow](img/accuracy/flow.png)", "",
                  "| model | h_min [m] | elements | time [s] | drag error | pressure-drop error |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {r['model']} | {r['h_min']} | {r['elements']} | {r['time_s']:.2f} | {r['drag_error']:.2e} | "
                  f"{r['pressure_drop_error']:.2e} |" for r in rows] + [""]
    if "coupling" in results:
        rows = results["coupling"]
        fig, ax = plt.subplots(figsize=(5.5, 3.8), dpi=100)
        pareto(ax, rows, "time_s", "error", "method", "two-way coupling: error vs time (tolerance)")
        save(fig, img / "coupling.png")
        lines += ["## Coupling: partitioned versus monolithic", "", "![coupling](img/accuracy/coupling.png)", "",
                  "| method | tolerance | time [s] | error in u |", "|---|---|---|---|"]
        lines += [f"| {r['method']} | {r['tol']:g} | {r['time_s']:.2f} | {r['error']:.2e} |" for r in rows] + [""]
    if "gradient" in results:
        rows = results["gradient"]
        lines += ["## Gradients: adjoint versus finite differences", "",
                  f"{rows[0]['design_variables']} design variables; one forward solve takes "
                  f"{rows[0]['forward_solve_s']:.3f} s.", "",
                  "| method | step h | relative error | time per full gradient [s] |", "|---|---|---|---|"]
        lines += [f"| {r['method']} | {'' if np.isnan(r['h']) else r['h']} | {r['error']:.1e} | "
                  f"{r['time_per_gradient_s']:.3g} |" for r in rows] + [""]
    write_text(out / ("accuracy_vs_time.md" if docs else "report.md"), "\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", nargs="+", default=["movers", "flow", "coupling", "gradient"],
                        choices=["movers", "flow", "coupling", "gradient"])
    parser.add_argument("--quick", action="store_true", help="fewer settings (a smoke run)")
    parser.add_argument("--docs", action="store_true", help="write docs/accuracy_vs_time.md and figures")
    parser.add_argument("--output", type=Path, default=Path("results/accuracy_vs_time"))
    args = parser.parse_args()
    studies = {"movers": mover_study, "flow": flow_study, "coupling": coupling_study, "gradient": gradient_study}
    results = {}
    for name in args.studies:
        print(f"{name} ...", flush=True)
        results[name], t = timed(studies[name], args.quick)
        print(f"{name}: {len(results[name])} rows in {t:.0f} s", flush=True)
    out = ROOT / "docs" if args.docs else args.output
    report(results, out, args.docs)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
