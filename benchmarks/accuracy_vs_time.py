"""What accuracy costs in time: Pareto plots for movers, flow, coupling and gradients.

Every setting's error is measured against a reference solution (the same
method on a finer setting) and plotted against its wall time, with the
recommended default marked. Studies:

* movers   -- increments, Newton tolerance, mesh size and linear solver, for
              each mover on the foil rotation (30 deg) and the beam;
* flow     -- drag and pressure drop versus time as the mesh is refined,
              Stokes and Navier-Stokes, on the beam in a channel;
* coupling -- partitioned versus monolithic two-way coupling versus tolerance;
* gradient -- adjoint versus finite differences (error and time per gradient);
* elements -- stabilized Q1/Q1 against Taylor-Hood Q2/Q1 at equal element count and at equal
              time: topFlow's objective of two fixed 0/1 designs (straight double pipes, a
              quarter-annulus bend) and the foil's drag, each in a fresh process (time, peak
              memory), against the finest Taylor-Hood mesh.

``--docs`` writes ``docs/accuracy_vs_time.md`` and its figures (``docs/img/accuracy``);
otherwise results go to ``--output``. About two minutes on two cores:

    python benchmarks/accuracy_vs_time.py --docs
    python benchmarks/accuracy_vs_time.py --studies movers --quick
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))     # run as a script: the package beside it
from benchmarks.accuracy_studies import (ELEMENT_PROBLEMS, FLOW_REFERENCE_H,  # noqa: E402
                                         MOVER_PROBLEMS, MOVER_SETTINGS, ROOT, STUDIES, timed)

# ---- report ---------------------------------------------------------------------------
def default_row(rows: list[dict]) -> dict:
    return next(r for r in rows if r["default"])


def mover_lines(rows: list[dict], problem: str) -> list[str]:
    lines = ["| mover | setting | value | time [s] | time / default | error vs reference | min skewness |",
             "|---|---|---|---|---|---|---|"]
    for mover in MOVER_SETTINGS:
        sel = [r for r in rows if r["problem"] == problem and r["mover"] == mover]
        t_default = default_row([r for r in sel if r["study"] == "parameter"])["time_s"]
        for r in sel:
            star = " (default)" if r["default"] else ""
            value = f"{r['value']:g}" if isinstance(r["value"], float) else r["value"]
            error = "" if np.isnan(r["error"]) else f"{r['error']:.2e}"
            lines.append(f"| {mover} | {r['parameter']} | {value}{star} | {r['time_s']:.2f} | "
                         f"{r['time_s'] / t_default:.2f} | {error} | {r['min_skewness']:.4f} |")
    return lines + [""]


def timing_spread(rows: list[dict]) -> float:
    """Largest spread (max/min - 1, percent) among the timings of identical default settings."""
    spread = 0.0
    for problem in MOVER_PROBLEMS:
        for mover in MOVER_SETTINGS:
            t = [r["time_s"] for r in rows if r["problem"] == problem and r["mover"] == mover and r["default"]]
            spread = max(spread, 100.0 * (max(t) / min(t) - 1.0))
    return spread


def recommendations(results: dict) -> list[str]:
    """The recommended default per mover (and for flow, coupling, gradients) with its measured cost."""
    lines = ["## Recommended defaults and what they cost", ""]
    if "movers" in results:
        lines += ["| mover | problem | default | time [s] | error vs reference | reference | reference time [s] | "
                  "speed-up |", "|---|---|---|---|---|---|---|---|"]
        for problem in MOVER_PROBLEMS:
            for mover, (key, _, ref_value, _) in MOVER_SETTINGS.items():
                d = default_row([r for r in results["movers"] if r["problem"] == problem and r["mover"] == mover
                                 and r["study"] == "parameter"])
                lines.append(f"| {mover} | {problem} | {key} = {d['value']:g} | {d['time_s']:.2f} | "
                             f"{d['error']:.1e} | {key} = {ref_value:g} | {d['reference_time_s']:.2f} | "
                             f"{d['reference_time_s'] / d['time_s']:.1f}x |")
        lines.append("")
    if "flow" in results:
        for model in ("stokes", "navier-stokes"):
            d = default_row([r for r in results["flow"] if r["model"] == model])
            lines.append(f"* {model}: h_min = {d['h_min']:g} m ({d['elements']:.0f} elements) costs "
                         f"{d['time_s']:.2f} s for a drag error of {d['drag_error']:.1e} and a pressure-drop "
                         f"error of {d['pressure_drop_error']:.1e} against h_min = {FLOW_REFERENCE_H:g} m.")
        stokes = default_row([r for r in results["flow"] if r["model"] == "stokes"])
        ns = default_row([r for r in results["flow"] if r["model"] == "navier-stokes"])
        lines.append(f"* Navier-Stokes costs {ns['time_s'] / stokes['time_s']:.1f}x Stokes on the same mesh "
                     "(a scene with `fluid = \"stokes\"` solves Stokes).")
    if "coupling" in results:
        d = default_row(results["coupling"])
        mono = [r for r in results["coupling"] if r["method"] == "monolithic" and r["error"] <= d["error"]]
        text = (f"* Two-way coupling: partitioned (IQN-ILS) at tol = {d['tol']:g} takes {d['time_s']:.2f} s "
                f"(error {d['error']:.1e})")
        if mono:
            best = min(mono, key=lambda r: r["time_s"])
            text += (f"; monolithic Newton reaches that error in {best['time_s']:.2f} s (tol = {best['tol']:g}, "
                     f"{best['time_s'] / d['time_s']:.2f}x the partitioned time)")
        lines.append(text + ". The monolithic form is the one whose factorization the adjoint reuses.")
    if "gradient" in results:
        rows = results["gradient"]
        adj = default_row(rows)
        best = min((r for r in rows if r["method"] != "adjoint"), key=lambda r: r["error"])
        lines.append(f"* Gradients: the adjoint gradient of the objective takes {adj['time_per_gradient_s']:.3f} s "
                     f"= {adj['time_per_gradient_s'] / adj['forward_solve_s']:.2f} forward solves; the most "
                     f"accurate forward difference (h = {best['h']:g}, error {best['error']:.1e}) would take "
                     f"{best['time_per_gradient_s']:.0f} s for the {adj['design_variables']:.0f} variables, "
                     f"{best['time_per_gradient_s'] / adj['time_per_gradient_s']:.0f}x more.")
    return lines + [""]


def report(out: Path, data: Path) -> None:
    """``accuracy_vs_time.md`` in ``out`` from the study CSVs in ``data`` (figures go to ``data``)."""
    from tofsi.runs.output import read_csv, write_text
    from tofsi.runs.plotting import pareto, plt, save
    results = {name: read_csv(data / f"{name}.csv") for name in STUDIES if (data / f"{name}.csv").exists()}
    rel = data.relative_to(out)
    lines = ["# What accuracy costs in time", "",
             f"Measured by `benchmarks/accuracy_vs_time.py` on {platform.machine()} "
             f"(2 cores, Python {platform.python_version()}); regenerate with "
             "`python benchmarks/accuracy_vs_time.py --docs` (`--studies NAME` redoes one study "
             "and rewrites this page from every study's CSV). Every error is against a reference "
             "solution of the same method on a finer setting; red stars mark the recommended defaults; "
             "times are wall-clock seconds and ratios are to the default's time.", ""]
    lines += recommendations(results)
    if "movers" in results:
        rows = results["movers"]
        lines += ["Movers: the error is the maximum nodal displacement error relative to the largest "
                  "displacement. The references are the same mover with "
                  + ", ".join(f"{k} = {ref:g} ({m})" for m, (k, _, ref, _) in MOVER_SETTINGS.items())
                  + ". Every run stiffens the first two element layers with the best factors of "
                  "`docs/mesh_motion_study.md`, tuned on the default mesh (on refined meshes the stiffened "
                  "layers are thinner, so quality need not improve with refinement). Solver rows compare sparse LU and AMG at the default setting; mesh rows show the "
                  "quality and time as the mesh is refined (refinement r divides both spacings by r). "
                  f"Each mover's three default rows repeat one setting: their times differ by up to "
                  f"{timing_spread(rows):.0f} %, the resolution of these sub-second timings.", ""]
        for problem in MOVER_PROBLEMS:
            fig, axes = plt.subplots(1, 3, figsize=(14, 3.8), dpi=100)
            for ax, mover in zip(axes, MOVER_SETTINGS, strict=True):
                sel = [r for r in rows if r["problem"] == problem and r["mover"] == mover and r["study"] == "parameter"]
                pareto(ax, sel, "time_s", "error", "parameter", f"{mover}: {sel[0]['parameter']}")
            name = f"movers_{problem.replace(' ', '_')}.png"
            save(fig, data / name)
            lines += [f"## Movers: {problem}", "", f"![movers {problem}]({rel / name})", ""]
            lines += mover_lines(rows, problem)
    if "flow" in results:
        rows = results["flow"]
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), dpi=100)
        pareto(axes[0], rows, "time_s", "drag_error", "model", "drag error vs time (mesh refinement)")
        pareto(axes[1], rows, "time_s", "pressure_drop_error", "model", "pressure-drop error vs time")
        save(fig, data / "flow.png")
        ns = sorted((r for r in rows if r["model"] == "navier-stokes"), key=lambda r: -r["h_min"])
        order = np.log(ns[0]["drag_error"] / ns[-1]["drag_error"]) / np.log(ns[0]["h_min"] / ns[-1]["h_min"])
        lines += ["## Flow: mesh refinement, Stokes and Navier-Stokes", "",
                  f"Beam in a channel (solid beam, alpha_max = 1e6, Re = 1), reference h_min = "
                  f"{FLOW_REFERENCE_H:g} m (h_max = 4 h_min). The drag converges at an observed order of "
                  f"{order:.1f}: the beam's corners and the Brinkman layer (width sqrt(mu/alpha) = 1e-3 m) "
                  "are not resolved; the pressure drop, an integral far from the corners, is within "
                  f"{max(r['pressure_drop_error'] for r in rows):.1e} of the reference on every mesh.", "",
                  f"![flow]({rel / 'flow.png'})", "",
                  "| model | h_min [m] | elements | time [s] | drag error | pressure-drop error |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {r['model']} | {r['h_min']:g} | {r['elements']:.0f} | {r['time_s']:.2f} | "
                  f"{r['drag_error']:.2e} | {r['pressure_drop_error']:.2e} |" for r in rows] + [""]
    if "coupling" in results:
        rows = results["coupling"]
        fig, ax = plt.subplots(figsize=(5.5, 3.8), dpi=100)
        pareto(ax, rows, "time_s", "error", "method", "two-way coupling: error vs time (tolerance)")
        save(fig, data / "coupling.png")
        lines += ["## Coupling: partitioned versus monolithic", "",
                  "Two-way coupled wall in a channel with the Yeoh mover (h = 0.05, E = 5e5); error in the "
                  "structure's displacement against a monolithic solve at tol = 1e-12.", "",
                  f"![coupling]({rel / 'coupling.png'})", "",
                  "| method | tolerance | time [s] | error in u |", "|---|---|---|---|"]
        lines += [f"| {r['method']} | {r['tol']:g} | {r['time_s']:.2f} | {r['error']:.2e} |" for r in rows] + [""]
    if "gradient" in results:
        rows = results["gradient"]
        adjoint = default_row(rows)
        fd = [r for r in rows if r["method"] != "adjoint"]
        fig, ax = plt.subplots(figsize=(5.5, 3.8), dpi=100)
        ax.loglog([r["time_per_gradient_s"] for r in fd], [r["error"] for r in fd], "o-", label="forward differences")
        for r in fd:
            ax.annotate(f"h={r['h']:g}", (r["time_per_gradient_s"], r["error"]), fontsize=7)
        ax.axvline(adjoint["time_per_gradient_s"], color="r", ls="--", label="adjoint (the reference)")
        ax.set_xlabel("time per full gradient [s]")
        ax.set_ylabel("error relative to the adjoint")
        ax.set_title("gradient: finite differences versus the adjoint", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
        save(fig, data / "gradient.png")
        lines += ["## Gradients: adjoint versus finite differences", "",
                  f"Compliance of the wall in a channel at a random design (h = 0.05), "
                  f"{adjoint['design_variables']:.0f} design variables; one forward solve takes "
                  f"{adjoint['forward_solve_s']:.3f} s. Forward differences on a sample of variables, error "
                  "against the adjoint gradient relative to its largest entry (the adjoint itself passes "
                  "the Taylor test at rate 2 in `tests/test_adjoint.py`).", "",
                  f"![gradient]({rel / 'gradient.png'})", "",
                  "| method | step h | error vs adjoint | time per full gradient [s] | time / adjoint |",
                  "|---|---|---|---|---|"]
        for r in rows:
            step = "" if np.isnan(r["h"]) else f"{r['h']:g}"
            error = "reference" if np.isnan(r["error"]) else f"{r['error']:.1e}"
            lines.append(f"| {r['method']} | {step} | {error} | {r['time_per_gradient_s']:.3g} | "
                         f"{r['time_per_gradient_s'] / adjoint['time_per_gradient_s']:.0f} |")
        lines.append("")
    if "elements" in results:
        lines += element_lines(results["elements"], data, rel)
    write_text(out / "accuracy_vs_time.md", "\n".join(lines) + "\n")


def element_lines(rows: list[dict], data: Path, rel: Path) -> list[str]:
    """The elements study: a Pareto plot per problem, the table, and the errors at equal time."""
    from tofsi.runs.plotting import pareto, plt, save
    fig, axes = plt.subplots(1, len(ELEMENT_PROBLEMS), figsize=(14, 3.8), dpi=100)
    for ax, problem in zip(axes, ELEMENT_PROBLEMS, strict=True):
        pareto(ax, [r for r in rows if r["problem"] == problem], "time_s", "error", "element",
               f"{problem}: error vs time (mesh refinement)")
    save(fig, data / "elements.png")
    lines = ["## Elements: stabilized Q1/Q1 against Taylor-Hood Q2/Q1", "",
             "Stokes flow through two fixed 0/1 designs of topFlow's scenes (straight pipes over the "
             "double pipe's inlets; a quarter annulus 0.7 < r < 0.9 joining the bend's inlet and outlet; "
             "alpha_max = 2.5e4, topFlow's objective phi) and the foil's drag (alpha_max = 1e8, the "
             "reaction load), on uniform meshes of n elements per unit length (the foil: graded, h_min "
             "given), each solve in a fresh process. The error is against Taylor-Hood on the finest mesh "
             f"({', '.join(f'{p}: {ELEMENT_PROBLEMS[p][5]:g}' for p in ELEMENT_PROBLEMS)}); time is the "
             "forward solve, memory the process's peak. The star marks the Taylor-Hood default mesh.", "",
             f"![elements]({rel / 'elements.png'})", "",
             "| problem | mesh | elements | element | value | error | time [s] | peak memory [MB] |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['problem']} | {r['size']:g} | {r['elements']:.0f} | {r['element']} | "
                     f"{r['value']:.5g} | {r['error']:.2e} | {r['time_s']:.2f} | {r['peak_mb']:.0f} |")
    lines.append("")
    for problem in ELEMENT_PROBLEMS:
        sel = [r for r in rows if r["problem"] == problem]
        q1 = sorted((r for r in sel if r["element"] == "q1q1"), key=lambda r: r["time_s"])
        t1, e1 = np.log([r["time_s"] for r in q1]), np.log([max(r["error"], 1e-16) for r in q1])
        pairs = []
        for r in (r for r in sel if r["element"] == "q2q1"):
            if t1[0] <= np.log(r["time_s"]) <= t1[-1]:     # Q1/Q1's error at this time, on its curve
                e = float(np.exp(np.interp(np.log(r["time_s"]), t1, e1)))
                pairs.append(f"{r['time_s']:.2g} s: Taylor-Hood {r['error']:.1e} ({r['elements']:.0f} elements), "
                             f"Q1/Q1 {e:.1e}")
        same = [(r, next(q for q in q1 if q["size"] == r["size"])) for r in sel if r["element"] == "q2q1"]
        ratio = [q["time_s"] / r["time_s"] for r, q in same]
        lines.append(f"* {problem}: on the same mesh Q1/Q1 takes {min(ratio):.2f}-{max(ratio):.2f} of Taylor-Hood's "
                     "time; at equal time (Q1/Q1's error interpolated on its refinement curve) "
                     + ("; ".join(pairs) if pairs else "the curves do not overlap") + ".")
    return lines + [""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", nargs="*", default=list(STUDIES), choices=list(STUDIES),
                        help="studies to (re)run; the report uses every study's saved CSV")
    parser.add_argument("--quick", action="store_true", help="fewer settings (a smoke run)")
    parser.add_argument("--docs", action="store_true", help="write docs/accuracy_vs_time.md and figures")
    parser.add_argument("--output", type=Path, default=Path("results/accuracy_vs_time"))
    args = parser.parse_args()
    from tofsi.runs.output import write_csv
    out = ROOT / "docs" if args.docs else args.output
    data = out / "img" / "accuracy" if args.docs else out
    for name in args.studies:
        print(f"{name} ...", flush=True)
        rows, t = timed(STUDIES[name], args.quick)
        write_csv(data / f"{name}.csv", rows)
        print(f"{name}: {len(rows)} rows in {t:.0f} s", flush=True)
    report(out, data)
    print(f"wrote {out / 'accuracy_vs_time.md'}")


if __name__ == "__main__":
    main()
