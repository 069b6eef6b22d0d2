"""The mesh-motion studies of Abdelhamid & Czekanski, on our four test problems.

Each study writes CSV files and figures to ``--output`` (default
``results/mesh_motion_study``) and appends its tables to ``summary.md``:

* ``triangulation`` -- spring analogy with diagonals 1-3, 2-4, both and selective
  (the paper's Table 1);
* ``one-layer``     -- stiffening factor 1 to 6 of the first element layer, for
  every mover (spring with each triangulation) and problem (Figs. 4, 6, 9;
  Table 2);
* ``two-layer``     -- heat maps of the first two layers' factors, coarse
  (1 to 6 by 0.5) then fine (best +- 0.5 by 0.1) (Figs. 5, 7, 10; Table 3);
* ``yeoh``          -- A20 from 1e-1 to 1e5 and kappa in {0.1, 1, 10, 100}:
  quality and time (Figs. 8, 9).

Every study runs on the scenes' graded meshes and, with ``--mesh uniform``,
on uniform meshes closer to the paper's. Run everything (about an hour on
two cores) or one study:

    python examples/mesh_motion_study.py all --jobs 2
    python examples/mesh_motion_study.py triangulation --mesh uniform

Without a study named it runs the smallest, ``triangulation`` on the graded
meshes (16 spring-analogy moves, about 20 seconds on two cores).

``TOFSI_EXAMPLE_SMALL=1`` runs every study on coarse meshes over two values
per swept key and one problem (seconds; the test suite does this).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from tofsi.coupling.motion import move_figures
from tofsi.runs.output import write_csv, write_text
from tofsi.runs.plotting import plot_sweep
from tofsi.optimization.study import Sweep, best, run_study

SCENES = Path(__file__).parent / "scenes"
PROBLEMS = {
    "beam": ("beam_in_channel", []),
    "foil-translation": ("foil_in_channel", ["deformation.mode=translation"]),
    "foil-rotation": ("foil_in_channel", ["deformation.mode=rotation"]),
    "foil-bending": ("foil_in_channel", ["deformation.mode=bending"]),
}
MESHES = {"graded": [], "uniform": ["mesh.h_min=0.0125", "mesh.h_max=0.0125", "mesh.growth=1.0"]}
MOVERS = ("spring", "linear", "yeoh")
DIAGONALS = ("1-3", "2-4", "both", "selective")
FACTORS = tuple(float(v) for v in np.round(np.arange(1.0, 6.0001, 0.25), 6))
COARSE = tuple(float(v) for v in np.arange(1.0, 6.0001, 0.5))       # two-layer grid, then
FINE = (0.5, 0.1)                                                    # best +- 0.5 by 0.1
A20 = tuple(10.0 ** k for k in range(-1, 6))
KAPPA = (0.1, 1.0, 10.0, 100.0)
if os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0":
    PROBLEMS = {k: PROBLEMS[k] for k in ("foil-rotation",)}
    MESHES = {name: ["mesh.h_min=0.05", "mesh.h_max=0.1"] for name in MESHES}
    FACTORS = COARSE = (1.0, 3.0)
    FINE, A20, KAPPA = (0.0, 1.0), (1.0, 1e3), (1.0,)


class Study:
    def __init__(self, output: Path, mesh: str, jobs: int):
        self.output, self.mesh, self.jobs = output / mesh, mesh, jobs
        self.tables: list[str] = []

    def run(self, problem: str, overrides: list[str], sweeps: list[Sweep]) -> list[dict]:
        scene, extra = PROBLEMS[problem]
        rows = run_study(SCENES / f"{scene}.toml", extra + MESHES[self.mesh] + overrides, sweeps,
                         move_figures, jobs=self.jobs)
        for row in rows:
            row["problem"] = problem
        return rows

    def table(self, title: str, header: list[str], lines: list[list]) -> None:
        text = [f"### {title} ({self.mesh} mesh)", "", "| " + " | ".join(header) + " |",
                "|" + "---|" * len(header)]
        text += ["| " + " | ".join(_fmt(v) for v in line) + " |" for line in lines]
        self.tables.append("\n".join(text) + "\n")
        print("\n".join(text), flush=True)

    def save(self) -> None:
        path = self.output / "summary.md"
        old = path.read_text() if path.exists() else ""
        write_text(path, old + "\n".join(self.tables))


def _fmt(v) -> str:
    return f"{v:.3f}" if isinstance(v, float) else str(v)


def triangulation(study: Study) -> None:
    rows = []
    for problem in PROBLEMS:
        rows += study.run(problem, ["mover.name=spring"], [Sweep("mover.spring.diagonals", DIAGONALS)])
    write_csv(study.output / "triangulation.csv", rows)
    for figure in ("min_skewness", "min_area_change", "max_area_change"):
        study.table(f"Spring analogy, {figure.replace('_', ' ')} by triangulation (paper Table 1)",
                    ["problem", *DIAGONALS],
                    [[p] + [r[figure] for r in rows if r["problem"] == p] for p in PROBLEMS])


def one_layer(study: Study) -> dict:
    best_rows = {}
    for mover in MOVERS:
        sweeps = [Sweep("mover.layers[0]", FACTORS)]
        if mover == "spring":
            sweeps.append(Sweep("mover.spring.diagonals", DIAGONALS))
        rows = []
        for problem in PROBLEMS:
            rows += study.run(problem, [f"mover.name={mover}"], sweeps)
        write_csv(study.output / f"one_layer_{mover}.csv", rows)
        for problem in PROBLEMS:
            sel = [r for r in rows if r["problem"] == problem]
            plot_sweep(study.output / f"one_layer_{mover}_{problem}.png", sel,
                       [s.key for s in sweeps], title=f"{mover}, {problem}: one stiffened layer")
            best_rows[(mover, problem)] = best(sel)
    study.table("Best one-layer stiffening (paper Table 2 for the spring)",
                ["mover", "problem", "min skewness", "factor", "diagonals"],
                [[m, p, r["min_skewness"], r["mover.layers[0]"], r.get("mover.spring.diagonals", "")]
                 for (m, p), r in best_rows.items()])
    return best_rows


def two_layer_grid(study: Study, mover: str, problem: str) -> tuple[list[dict], list[dict]]:
    """The two-layer grid search: coarse (1 to 6 by 0.5), then fine (best +- 0.5 by 0.1);
    one move per row."""
    extra = ["mover.spring.diagonals=both"] if mover == "spring" else []
    rows = study.run(problem, [f"mover.name={mover}", *extra],
                     [Sweep("mover.layers[0]", COARSE), Sweep("mover.layers[1]", COARSE)])
    top = best(rows)

    def window(c):
        half, step = FINE
        return tuple(float(v) for v in np.round(np.arange(max(1.0, c - half), c + half + 1e-4, step), 6))
    fine = study.run(problem, [f"mover.name={mover}", *extra],
                     [Sweep("mover.layers[0]", window(top["mover.layers[0]"])),
                      Sweep("mover.layers[1]", window(top["mover.layers[1]"]))])
    write_csv(study.output / f"two_layer_{mover}_{problem}.csv", rows + fine)
    return rows, fine


def two_layer(study: Study, unstiffened: dict, one: dict) -> None:
    lines = []
    for mover in MOVERS:
        for problem in PROBLEMS:
            rows, fine = two_layer_grid(study, mover, problem)
            keys = ["mover.layers[0]", "mover.layers[1]"]
            plot_sweep(study.output / f"two_layer_{mover}_{problem}_coarse.png", rows, keys,
                       title=f"{mover}, {problem}: two stiffened layers")
            plot_sweep(study.output / f"two_layer_{mover}_{problem}_fine.png", fine, keys,
                       title=f"{mover}, {problem}: two stiffened layers (refined)")
            top = best(rows + fine)
            lines.append([mover, problem, unstiffened[(mover, problem)], one[(mover, problem)]["min_skewness"],
                          top["min_skewness"], top["mover.layers[0]"], top["mover.layers[1]"]])
    study.table("Minimum skewness without, with one and with two stiffened layers (paper Table 3)",
                ["mover", "problem", "none", "one layer", "two layers", "factor 1", "factor 2"], lines)


def yeoh_parameters(study: Study) -> None:
    a20 = A20
    rows = []
    for problem in PROBLEMS:
        rows += study.run(problem, ["mover.name=yeoh"],
                          [Sweep("mover.yeoh.A20", a20), Sweep("mover.yeoh.kappa", KAPPA)])
    write_csv(study.output / "yeoh_parameters.csv", rows)
    for problem in PROBLEMS:
        sel = [dict(r, kappa=f"kappa={r['mover.yeoh.kappa']:g}") for r in rows if r["problem"] == problem]
        plot_sweep(study.output / f"yeoh_parameters_{problem}.png", sel, ["mover.yeoh.A20", "kappa"],
                   title=f"Yeoh mover, {problem}: A20 and kappa")
    study.table("Yeoh: minimum skewness by A20 (kappa = 1) (paper Fig. 8)", ["problem", *[f"{a:g}" for a in a20]],
                [[p] + [r["min_skewness"] for r in rows if r["problem"] == p and r["mover.yeoh.kappa"] == 1.0]
                 for p in PROBLEMS])
    study.table("Yeoh: wall time [s] by A20 (kappa = 1)", ["problem", *[f"{a:g}" for a in a20]],
                [[p] + [r["wall_time_s"] for r in rows if r["problem"] == p and r["mover.yeoh.kappa"] == 1.0]
                 for p in PROBLEMS])


def unstiffened(study: Study) -> dict:
    out = {}
    for mover in MOVERS:
        extra = ["mover.spring.diagonals=both"] if mover == "spring" else []
        for problem in PROBLEMS:
            out[(mover, problem)] = study.run(problem, [f"mover.name={mover}", *extra, "mover.layers=[]"],
                                              [])[0]["min_skewness"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", nargs="?", default="triangulation",
                        choices=["triangulation", "one-layer", "two-layer", "yeoh", "all"],
                        help="the study to run (default: triangulation, the smallest)")
    parser.add_argument("--mesh", choices=list(MESHES), default="graded")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--output", type=Path, default=Path("results/mesh_motion_study"))
    args = parser.parse_args()
    study = Study(args.output, args.mesh, args.jobs)
    try:
        if args.study in ("triangulation", "all"):
            triangulation(study)
        if args.study in ("one-layer", "two-layer", "all"):
            one = one_layer(study)
            if args.study != "one-layer":
                two_layer(study, unstiffened(study), one)
        if args.study in ("yeoh", "all"):
            yeoh_parameters(study)
    finally:
        study.save()
    print(f"wrote {study.output}")


if __name__ == "__main__":
    main()
