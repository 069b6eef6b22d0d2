"""Beyond the paper: stiffening factors tuned by gradients, and mesh motion confined to a band.

Two studies; each writes CSV files to ``--output`` (default ``results/tuning_band_study``)
and its markdown tables to ``tables.md`` there (with ``--docs PATH`` also between the
markers ``<!-- tuning-band-study:tuning:start -->`` / ``...:end -->`` (and ``band``) of
that page, e.g. ``docs/mesh_motion_study.md``):

* ``tuning`` -- the four problems x three movers on the graded meshes: minimum skewness
  with (a) no stiffening, (b) the best point of the two-layer grid search of
  ``mesh_motion_study.py`` (coarse 1 to 6 by 0.5, then best +- 0.5 by 0.1; its moves
  counted), (c) :func:`tofsi.optimization.tuning.tune` given a tenth of the grid's mover solves
  (forward moves and adjoint solves together), (d) the paper's best column (Table 3);
* ``band`` -- full domain against the automatic band (:mod:`tofsi.mesh.band`) and a
  narrower one: the 8 degree foil rotation of ``benchmarks/mover_speed.py`` at its mesh
  sizes (each mover: minimum skewness, minimum / maximum area change, time of the
  mesh motion, setup of the band included), and the twelve problem x mover cases;
* ``reach`` -- why no band meets both the quality and the time target on that
  benchmark: at one mesh size (``--reach-refine``, default the largest), the band's
  reach swept from 8 to 15 times the largest displacement, against the full-domain
  solution's displacement on the band's edge and the share of the quads it moves.

    python examples/tuning_band_study.py all --jobs 2 --docs docs/mesh_motion_study.md
    python examples/tuning_band_study.py band --refine 2.2 3.8

or the band study split into runs side by side, then its tables from their CSV files:

    python examples/tuning_band_study.py band --refine 2.2 3.8 6.9
    python examples/tuning_band_study.py band --refine 12 --no-problems --movers spring --output results/b1
    python examples/tuning_band_study.py band --refine 12 --no-problems --movers linear yeoh --output results/b2
    python examples/tuning_band_study.py tables --merge results/b1 results/b2 --docs docs/mesh_motion_study.md
    python examples/tuning_band_study.py reach --movers linear yeoh --docs docs/mesh_motion_study.md

Without a study named it runs a small one: the band study on the benchmark's
smallest mesh (``band --refine 2.2 --no-problems``: about 10^4 nodes, three
movers, under a minute on two cores).

Times are the CPU time of the process (wall time beside it): on a shared machine
it is the fair measure of the work.

``TOFSI_EXAMPLE_SMALL=1`` runs both on coarse meshes, one problem and the smallest grid
(seconds; the test suite does this).

The grid search reuses ``two_layer_<mover>_<problem>.csv`` from ``--grid`` (the
output of ``mesh_motion_study.py two-layer``) when present, else runs it.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import tofsi
from tofsi.core.errors import NumericalError
from tofsi.coupling.motion import moved_quality, motion_setup
from tofsi.runs.output import read_csv, write_csv, write_text
from tofsi.physics.mesh_motion import MeshMotion
from tofsi.optimization.study import best
from tofsi.optimization.tuning import tune

from mesh_motion_study import MESHES, MOVERS, PROBLEMS, SCENES, Study, two_layer_grid  # its sibling script

PAPER_BEST = {  # Abdelhamid & Czekanski, Table 3 ("Summary of all minimum skewness results"):
    "spring": [0.493, 0.506, 0.510, 0.527],    # two layers
    "linear": [0.377, 0.470, 0.446, 0.418],    # three layers
    "yeoh": [0.512, 0.613, 0.683, 0.691],      # two layers
}
REFINE = [2.2, 3.8, 6.9, 12.0]               # benchmarks/mover_speed.py: about 1e4 .. 2.4e5 nodes
MULTIPLES = [8.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0]   # reach study: band reach / largest displacement
SMALL = os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0"
if SMALL:
    REFINE = [0.5]
    MULTIPLES = [5.0, 15.0]


def scene(problem: str, *overrides):
    name, extra = PROBLEMS[problem]
    return tofsi.load_scene(SCENES / f"{name}.toml", [*extra, *MESHES["graded"], *overrides])


def mover_overrides(mover: str) -> list[str]:
    """As in the two-layer grid search: fixed (both) diagonals for the spring analogy."""
    return [f"mover.name={mover}"] + (["mover.spring.diagonals=both"] if mover == "spring" else [])


def _fmt(v, digits=3) -> str:
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def markdown_table(header, lines) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_fmt(v) for v in line) + " |" for line in lines]
    return "\n".join(out) + "\n"


# ---- tuning ----------------------------------------------------------------------------------
def grid_search(study: Study, grid_dir: Path | None, mover: str, problem: str) -> list[dict]:
    """The grid's rows: from an earlier run (``grid_dir`` or this study's own output) or run now."""
    name = f"two_layer_{mover}_{problem}.csv"
    for folder in (grid_dir, study.output):
        if folder is not None and (folder / name).is_file():
            return read_csv(folder / name)
    rows, fine = two_layer_grid(study, mover, problem)
    return rows + fine


def unstiffened(mover: str, problem: str) -> float:
    sc = scene(problem, *mover_overrides(mover), "mover.layers=[]")
    setup = motion_setup(sc)
    try:
        return moved_quality(setup, setup.motion.move(setup.prescribed).displacement).min_skewness
    except NumericalError as err:
        return err.diagnostic["quality"]["min_skewness"]


def tuning_study(output: Path, grid_dir: Path | None, jobs: int) -> str:
    study = Study(output, "graded", jobs)
    rows = []
    for mover in MOVERS:
        for k, problem in enumerate(PROBLEMS):
            grid = grid_search(study, grid_dir, mover, problem)
            top = best(grid)
            budget = max(4, len(grid) // 10)          # 4: a move and an adjoint per KS stage (small runs)
            print(f"{mover} {problem}: grid of {len(grid)} moves, best {top['min_skewness']:.4f}; "
                  f"tuning with {budget} solves", flush=True)
            result = tune(scene(problem, *mover_overrides(mover), f"tune.max_solves={budget}"))
            rows.append({"mover": mover, "problem": problem, "none": unstiffened(mover, problem),
                         "grid_best": top["min_skewness"], "grid_factor_1": top["mover.layers[0]"],
                         "grid_factor_2": top["mover.layers[1]"], "grid_moves": len(grid),
                         "tuned": result.min_skewness, "tuned_factors": " ".join(f"{f:.2f}" for f in result.layer_factors),
                         "tuned_moves": result.moves, "tuned_adjoints": result.adjoints,
                         "tuned_min_area_change": result.min_area_change,
                         "tuned_max_area_change": result.max_area_change, "tuned_time_s": result.wall_time_s,
                         "paper_best": PAPER_BEST[mover][k], "stop": result.stop})
            r = rows[-1]
            print(f"   tuned {r['tuned']:.4f} with {r['tuned_moves']} moves + {r['tuned_adjoints']} adjoints "
                  f"({r['tuned_time_s']:.0f} s): {r['tuned_factors']}", flush=True)
    write_csv(output / "tuning.csv", rows)
    return tuning_table(rows, study, grid_dir)


def tuning_table(rows: list[dict], study: Study, grid_dir: Path | None) -> str:
    lines = []
    for r in rows:
        grid_time = sum(g["run_time_s"] for g in grid_search(study, grid_dir, r["mover"], r["problem"]))
        moves, adjoints = int(r["tuned_moves"]), int(r["tuned_adjoints"])
        solves = moves + adjoints
        factors = r["tuned_factors"].split()
        shown = " ".join(factors[:4]) + (" ..." if len(factors) > 4 else "")
        met = "yes" if r["tuned"] >= r["grid_best"] and 10 * solves <= r["grid_moves"] else "no"
        lines.append([r["mover"], r["problem"], r["none"], f"{r['grid_best']:.4f}",
                      f"{r['grid_factor_1']:g}, {r['grid_factor_2']:g}", int(r["grid_moves"]), f"{grid_time:.0f}",
                      f"{r['tuned']:.4f}", shown, f"{moves} + {adjoints}",
                      f"{r['tuned_time_s']:.0f}", r["paper_best"], met])
    return markdown_table(["mover", "problem", "none", "grid best", "grid factors", "grid moves", "grid time [s]",
                           "tuned", "tuned factors (layers 1-4)", "tuned solves (moves + adjoints)",
                           "tuned time [s]", "paper best (Table 3)", "tuned >= grid, <= 1/10 solves"], lines)


# ---- band ------------------------------------------------------------------------------------
def benchmark_overrides(refine: float, mover: str) -> list[str]:
    """The case of benchmarks/mover_speed.py: the foil rotated by 8 degrees, graded mesh refined."""
    return [f"mesh.h_min={0.0125 / refine}", f"mesh.h_max={0.05 / refine}", "deformation.mode=rotation",
            "deformation.rotation_deg=8", f"mover.name={mover}"] + (["mover.linear.chi=1"] if mover == "linear" else [])


def timed_move(sc, setup) -> dict:
    """Build the scene's mesh motion on the shared mesh and move it: figures, and the time of
    both as wall time and as this process's CPU time (on a shared machine the CPU time is the
    fair measure: SuperLU and the kernels run on one thread, ``solver.blas_threads = 1``)."""
    size = float(np.linalg.norm(setup.prescribed, axis=1).max())
    t0, c0 = time.perf_counter(), time.process_time()
    motion = MeshMotion(setup.mesh, sc, motion_size=size)
    try:
        result = motion.move(setup.prescribed)
    except NumericalError as err:
        q = err.diagnostic.get("quality", {})
        return {"valid": False, "time_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                "moving": motion.moving.size,
                **{k: q.get(k, np.nan) for k in ("min_skewness", "min_area_change", "max_area_change")}}
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    q = moved_quality(type(setup)(setup.mesh, motion, setup.prescribed), result.displacement)
    return {"valid": q.n_inverted == 0, "time_s": elapsed, "cpu_s": cpu, "moving": motion.moving.size,
            "min_skewness": q.min_skewness, "min_area_change": q.min_area_change,
            "max_area_change": q.max_area_change,
            "reach_m": None if motion.band is None else motion.band.reach}


BANDS = {"full": [], "auto": ["mover.band.mode=auto"],
         "auto x5": ["mover.band.mode=auto", "mover.band.motion_multiple=5"]}


def band_study(output: Path, refine: list[float], problems: bool = True, movers=MOVERS) -> str:
    """The four problems first (unless ``problems`` is False), then the benchmark sizes from
    small to large; ``band.csv`` is rewritten after every row, so a stopped run keeps what it
    measured."""
    rows = []

    def add(row):
        rows.append(row)
        write_csv(output / "band.csv", rows)
        print(" ".join(f"{k}={_fmt(v, 4)}" for k, v in row.items()), flush=True)
    for mover in movers if problems else ():
        for problem in PROBLEMS:
            base = mover_overrides(mover)
            setup = motion_setup(scene(problem, *base))
            for name, extra in BANDS.items():
                add({"case": problem, "refine": 1.0, "nodes": setup.mesh.n_nodes, "mover": mover, "band": name,
                     **timed_move(scene(problem, *base, *extra), setup)})
    for r in refine:
        for mover in movers:
            setup = motion_setup(tofsi.load_scene(SCENES / "foil_in_channel.toml", benchmark_overrides(r, mover)))
            for name, extra in BANDS.items():
                sc = tofsi.load_scene(SCENES / "foil_in_channel.toml", benchmark_overrides(r, mover) + extra)
                add({"case": "rotation 8 deg", "refine": r, "nodes": setup.mesh.n_nodes, "mover": mover,
                     "band": name, **timed_move(sc, setup)})
    return band_tables(rows)


def band_tables(rows: list[dict]) -> str:
    def full_of(row):
        return next(f for f in rows if f["band"] == "full" and f["case"] == row["case"]
                    and f["refine"] == row["refine"] and f["mover"] == row["mover"])
    bench, problems = [], []
    for row in rows:
        if row["band"] == "full":
            continue
        full = full_of(row)
        within = "yes" if abs(row["min_skewness"] - full["min_skewness"]) <= 0.01 else "no"
        within = within if full["valid"] else "(full invalid)"
        line = [row["mover"], row["band"], full["min_skewness"], row["min_skewness"], within,
                f"{full['min_area_change']:.3f} / {full['max_area_change']:.3f}",
                f"{row['min_area_change']:.3f} / {row['max_area_change']:.3f}",
                f"{row['moving'] / full['moving']:.2f}", full["cpu_s"], row["cpu_s"],
                f"{row['cpu_s'] / full['cpu_s']:.2f}", f"{row['time_s'] / full['time_s']:.2f}"]
        if row["case"] == "rotation 8 deg":
            bench.append([int(row["nodes"]), *line])
        else:
            problems.append([row["case"], *line])
    head = ["mover", "band", "min skew full", "min skew band", "within 0.01", "area change full (min / max)",
            "area change band", "band quads / full", "CPU full [s]", "CPU band [s]", "CPU ratio",
            "wall ratio"]
    return ("Foil rotated by 8 degrees (benchmarks/mover_speed.py), graded meshes refined:\n\n"
            + markdown_table(["nodes", *head], bench)
            + "\nThe four problems, graded meshes (scene defaults):\n\n" + markdown_table(["problem", *head], problems))


# ---- reach ------------------------------------------------------------------------------------
def reach_study(output: Path, refine: float, movers, multiples=MULTIPLES) -> str:
    """The band's reach swept at one benchmark mesh: quality loss, share of the quads, CPU time,
    and how much the full-domain solution still moves where the band holds the mesh fixed."""
    rows = []
    for mover in movers:
        base = benchmark_overrides(refine, mover)
        setup = motion_setup(tofsi.load_scene(SCENES / "foil_in_channel.toml", base))
        size = float(np.linalg.norm(setup.prescribed, axis=1).max())
        c0 = time.process_time()                # as timed_move: building the motion included
        motion = MeshMotion(setup.mesh, tofsi.load_scene(SCENES / "foil_in_channel.toml", base), motion_size=size)
        u_full = motion.move(setup.prescribed).displacement
        full_cpu = time.process_time() - c0
        full_q = moved_quality(type(setup)(setup.mesh, motion, setup.prescribed), u_full)
        moved = np.linalg.norm(u_full, axis=1)[setup.mesh.quads[motion.movable]].max(axis=1) / size
        for multiple in multiples:
            sc = tofsi.load_scene(SCENES / "foil_in_channel.toml",
                                  base + ["mover.band.mode=auto", f"mover.band.motion_multiple={multiple}"])
            row = timed_move(sc, setup)
            band = MeshMotion(setup.mesh, sc, motion_size=size).band
            edge = float(np.linalg.norm(u_full[band.edge_nodes], axis=1).max()) / size
            rows.append({"mover": mover, "nodes": setup.mesh.n_nodes, "multiple": multiple,
                         "reach_m": row["reach_m"], "share": row["moving"] / motion.movable.size,
                         "min_skewness_full": full_q.min_skewness, "min_skewness": row["min_skewness"],
                         "loss": full_q.min_skewness - row["min_skewness"], "cpu_full_s": full_cpu,
                         "cpu_s": row["cpu_s"], "cpu_ratio": row["cpu_s"] / full_cpu, "edge_motion": edge,
                         "quads_moved_5pct": float(np.mean(moved > 0.05)),
                         "quads_moved_10pct": float(np.mean(moved > 0.10))})
            write_csv(output / "reach.csv", rows)
            print(" ".join(f"{k}={_fmt(v, 4)}" for k, v in rows[-1].items()), flush=True)
    return reach_table(rows)


def reach_table(rows: list[dict]) -> str:
    lines = [[r["mover"], int(r["nodes"]), r["multiple"], r["reach_m"], f"{r['share']:.2f}",
              f"{r['min_skewness_full']:.4f}", f"{r['min_skewness']:.4f}", f"{r['loss']:.4f}",
              "yes" if r["loss"] <= 0.01 else "no", f"{r['cpu_ratio']:.2f}",
              "yes" if r["cpu_ratio"] <= 0.5 else "no", f"{r['edge_motion']:.2f}"] for r in rows]
    spread = sorted({(r["mover"], f"{r['quads_moved_5pct']:.2f}", f"{r['quads_moved_10pct']:.2f}") for r in rows})
    note = "; ".join(f"{m}: {a} / {b}" for m, a, b in spread)
    return (markdown_table(["mover", "nodes", "reach / largest displacement", "reach [m]", "band quads / full",
                            "min skew full", "min skew band", "loss", "loss <= 0.01", "CPU ratio",
                            "CPU ratio <= 0.5", "full-domain motion on the band edge / largest"], lines)
            + f"\nShare of the movable quads the full-domain solve moves by more than 5 % / 10 % of "
              f"the largest displacement: {note}.\n")


# ---- output ----------------------------------------------------------------------------------
def update_docs(path: Path, parts: dict) -> None:
    """Put each study's tables between its markers ``<!-- tuning-band-study:<key>:start/end -->``."""
    text = path.read_text()
    for key, table in parts.items():
        start_mark, end_mark = (f"<!-- tuning-band-study:{key}:{end} -->" for end in ("start", "end"))
        start, end = text.index(start_mark) + len(start_mark), text.index(end_mark)
        text = text[:start] + "\n" + table.strip() + "\n" + text[end:]
    write_text(path, text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", nargs="?", choices=["tuning", "band", "reach", "all", "tables"],
                        help="tables: rebuild the tables from the CSV files of earlier runs "
                             "(none: the band study on the benchmark's smallest mesh)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes of the grid search")
    parser.add_argument("--refine", type=float, nargs="*", default=REFINE,
                        help="band: the benchmark's mesh refinements (none: skip the benchmark)")
    parser.add_argument("--reach-refine", type=float, default=REFINE[-1],
                        help="reach: the benchmark's mesh refinement of the sweep")
    parser.add_argument("--no-problems", action="store_true", help="band: only the benchmark meshes")
    parser.add_argument("--movers", nargs="+", choices=MOVERS, default=MOVERS, help="band, reach: these movers only")
    parser.add_argument("--grid", type=Path, default=Path("results/mesh_motion_study/graded"),
                        help="folder of an earlier two-layer grid search (mesh_motion_study.py)")
    parser.add_argument("--output", type=Path, default=Path("results/tuning_band_study"))
    parser.add_argument("--docs", type=Path, help="page whose marked section gets the tables")
    parser.add_argument("--merge", type=Path, nargs="*", default=[],
                        help="tables: also the band.csv of these folders (a band study split into "
                             "runs by --movers / --refine / --no-problems)")
    args = parser.parse_args()
    if args.study is None:                          # the small default: one benchmark mesh
        args.study, args.refine, args.no_problems = "band", args.refine[:1], True
        print(f"no study named: the band study at the benchmark mesh refinement {args.refine[0]:g} "
              "(see --help for the others)", flush=True)
    parts = {}
    previous = args.output / "tables.md"
    if previous.is_file():                          # keep the other study's tables
        text = previous.read_text()
        for key in ("tuning", "band", "reach"):
            tag = f"<!-- {key} -->"
            if tag in text:
                parts[key] = text.split(tag)[1]
    if args.study in ("tuning", "all"):
        parts["tuning"] = tuning_study(args.output, args.grid, args.jobs)
    if args.study in ("band", "all"):
        parts["band"] = band_study(args.output, args.refine, problems=not args.no_problems,
                                   movers=args.movers)
    if args.study in ("reach", "all"):
        parts["reach"] = reach_study(args.output, args.reach_refine,
                                     ["linear"] if args.study == "all" else args.movers)
    if args.study == "tables":
        if (args.output / "reach.csv").is_file():
            parts["reach"] = reach_table(read_csv(args.output / "reach.csv"))
        if (args.output / "tuning.csv").is_file():
            parts["tuning"] = tuning_table(read_csv(args.output / "tuning.csv"),
                                           Study(args.output, "graded", args.jobs), args.grid)
        band_rows = [row for folder in (args.output, *args.merge) if (folder / "band.csv").is_file()
                     for row in read_csv(folder / "band.csv")]
        if band_rows:
            order = {name: k for k, name in enumerate([*PROBLEMS, *MOVERS, *BANDS])}
            band_rows.sort(key=lambda r: (r["case"] != "rotation 8 deg", r["refine"], order[r["mover"]],
                                          order.get(r["case"], -1), order[r["band"]]))
            parts["band"] = band_tables(band_rows)
    section = "".join(f"<!-- {key} -->\n{parts[key].strip()}\n<!-- {key} -->\n" for key in ("tuning", "band", "reach")
                      if key in parts)
    write_text(previous, section)
    if args.docs:
        update_docs(args.docs, parts)
    print(section)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
