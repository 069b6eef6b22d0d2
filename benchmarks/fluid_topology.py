"""Published fluid-topology benchmarks on three meshes: the double pipes of Borrvall & Petersson
(2003) and of Alexandersen's topFlow (2023) and topFlow's pipe bend, each with its published
settings (benchmarks/published.py changes one setting at a time on the published mesh).

For every case and mesh the script runs ``tofsi optimize`` on the shipped scene with only the
element size changed (a finished run in the output folder is reused), then reports the
objective of the optimized design, its non-discreteness, the objective of the same design
thresholded to 0/1 at the fluid bound (the fluid elements are the most fluid ones), the
topology (two pipes or merged), iterations and time, beside the published value:

    python benchmarks/fluid_topology.py [--cases bp_double_pipe ...] [--meshes 50 100]
                                        [--output results/benchmarks/fluid_topology] [--pictures DIR]

``--meshes`` are elements per unit length (default: each case's three; the published mesh
density among them). Runs are long (the finest take about an hour each on two cores); run
them under ``nice``, one at a time.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path


import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "examples" / "scenes"
CASES = {   # scene: (published value, source, elements per unit length of the three meshes)
    "bp_double_pipe": (25.67, "Borrvall & Petersson 2003, 100 x 100", (24, 50, 100)),
    "bp_double_pipe_long": (27.64, "Borrvall & Petersson 2003, 150 x 100", (24, 50, 100)),
    "topflow_double_pipe": (22.0956, "topFlow, 102 x 102 Q1/Q1", (30, 54, 102)),
    "topflow_double_pipe_long": (23.5732, "topFlow, 153 x 102 Q1/Q1", (30, 54, 102)),
    "topflow_pipe_bend": (9.1862, "topFlow, 100 x 100 Q1/Q1", (20, 50, 100)),
    "pipe_bend": (None, "no published value with these settings", (50,)),     # the bottom outlet
}


def overrides(n: int) -> list[str]:
    return [f"mesh.h_min={1.0 / n!r}", f"mesh.h_max={1.0 / n!r}"]


def run(case: str, n: int, folder: Path) -> dict:
    """``tofsi optimize`` of a case on a mesh of ``n`` elements per unit length (reused if done)."""
    if not (folder / "result.json").is_file():
        args = [sys.executable, "-m", "tofsi.cli", "optimize", str(SCENES / f"{case}.toml"),
                "--output", str(folder), "--json", "-q"]
        for o in overrides(n):
            args += ["--set", o]
        t0 = time.perf_counter()
        proc = subprocess.run(args, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{case} at {n}: {proc.stderr[-2000:]}")
        print(f"  {case} {n}: {time.perf_counter() - t0:.0f} s", flush=True)
    return json.loads((folder / "result.json").read_text())


def topology(mesh, rho) -> str:
    """Two pipes (fluid along y = 1/4 and 3/4 at mid-length) or merged (fluid at y = 1/2)."""
    c = mesh.centroids
    mid = 0.5 * mesh.xs[-1]

    def fluid_at(y):
        near = (np.abs(c[:, 0] - mid) < 0.05) & (np.abs(c[:, 1] - y) < 0.03)
        return float((1 - rho)[near].mean())
    pipes = min(fluid_at(0.25), fluid_at(0.75)) > 0.5
    merged = fluid_at(0.5) > 0.5
    return "two pipes" if pipes and not merged else "merged" if merged and not pipes else "other"


def analyse(case: str, n: int, folder: Path) -> dict:
    """Figures of a finished run, and its design thresholded to 0/1 at the fluid bound."""
    import tofsi
    from tofsi.optimization.optimize import non_discreteness
    result = run(case, n, folder)
    scene = tofsi.load_scene(SCENES / f"{case}.toml", overrides(n))
    p = tofsi.Problem(scene)
    p.set_stage(dataclasses.replace(p.params, brinkman_q=scene.design.brinkman_q[-1]))   # the final interpolation
    gamma = np.load(folder / "design.npy")
    rho = p.densities(gamma)
    d = p.map.design
    n_fluid = int(round(scene.design.volume_fraction * d.size))
    sharp = np.ones(d.size)                  # no filter, no projection: gamma is rho
    sharp[np.argsort(rho[d], kind="stable")[:n_fluid]] = 0.0
    thresholded = p.evaluate(sharp)[0]
    again = p.evaluate(gamma)[0]              # the stored design with this code: same objective?
    history = json.loads((folder / "history.json").read_text())
    published = CASES[case][0]
    versus = (lambda v: 100 * (v / published - 1)) if published else (lambda v: float("nan"))
    return {"case": case, "n": n, "mesh": f"{p.model.mesh.nx} x {p.model.mesh.ny}",
            "objective": result["objective"], "vs_published_percent": versus(result["objective"]),
            "objective_reevaluated": again,
            "non_discreteness_percent": non_discreteness(rho[d]), "thresholded": thresholded,
            "thresholded_vs_published_percent": versus(thresholded),
            "topology": topology(p.model.mesh, rho) if "double_pipe" in case else "-", "iterations": result["iterations"],
            "stages": len({h["stage"] for h in history}), "wall_time_s": result["wall_time_s"],
            "published": published or float("nan")}


def picture(case: str, n: int, folder: Path, out: Path) -> None:
    """A small picture of the design (black: solid) over the flow speed."""
    import tofsi
    from tofsi.runs.plotting import plot_design
    scene = tofsi.load_scene(SCENES / f"{case}.toml", overrides(n))
    p = tofsi.Problem(scene)
    p.set_stage(dataclasses.replace(p.params, brinkman_q=scene.design.brinkman_q[-1]))
    gamma = np.load(folder / "design.npy")
    rho, state = p.densities(gamma), p.solve(gamma)
    m = p.model.mesh
    v = state.w[:p.model.flow.n_velocity].reshape(-1, 2)[: m.n_nodes]
    plot_design(out / f"{case}_{n}.png", m.points, m.quads, rho, np.linalg.norm(v, axis=1),
                title=f"{m.nx} x {m.ny} elements", width=3.6)


def table(rows: list[dict]) -> str:
    lines = ["| case | mesh | J optimized | vs published | grey | J thresholded 0/1 | vs published | "
             "topology | iterations | time |", "|---|---|---|---|---|---|---|---|---|---|"]
    def percent(v):
        return "-" if np.isnan(v) else f"{v:+.1f} %"
    for r in rows:
        lines.append(f"| {r['case']} | {r['mesh']} | {r['objective']:.3f} | {percent(r['vs_published_percent'])} | "
                     f"{r['non_discreteness_percent']:.1f} % | {r['thresholded']:.3f} | "
                     f"{percent(r['thresholded_vs_published_percent'])} | {r['topology']} | {r['iterations']} | "
                     f"{r['wall_time_s']:.0f} s |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--meshes", nargs="*", type=int, help="elements per unit length")
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks/fluid_topology"))
    parser.add_argument("--pictures", type=Path, help="write small design pictures here")
    args = parser.parse_args()
    rows = []
    for case in args.cases:
        for n in args.meshes or CASES[case][2]:
            folder = args.output / f"{case}_{n}"
            rows.append(analyse(case, n, folder))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
            if args.pictures:
                args.pictures.mkdir(parents=True, exist_ok=True)
                picture(case, n, folder, args.pictures)
    args.output.mkdir(parents=True, exist_ok=True)
    with open(args.output / "fluid_topology.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(table(rows))


if __name__ == "__main__":
    main()
