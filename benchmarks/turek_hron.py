"""Turek & Hron's FSI benchmark (CSM1, CSM2, FSI1) and the DFG 2D-1 cylinder, mesh by mesh, and
the measurements of where the remaining differences come from.

Every case is a shipped scene (``examples/scenes/turek_hron_*.toml``, ``dfg_cylinder.toml``)
solved at the element sizes ``h_min = 5 mm / 2^level`` at the bodies (level 0: 4 elements
through the flag's thickness, 20 across the cylinder), each run in a fresh process: its
figures at the tip A and on the bodies, the unknowns, the process CPU seconds, the wall
seconds, the peak memory and the load average (``os.getloadavg``) before and after.

* ``run`` solves the cases at the levels (a finished run's JSON in ``--output`` is reused;
  ``--force`` runs it again);
* ``studies`` solves the variants that measure each remaining difference: the Brinkman
  friction ``alpha_max`` (FSI1, DFG), the cylinder's representation (the symmetric staircase,
  a staircase on grid lines that miss the centre, the area fraction as density), the flag's
  clamp (the straight edge at x = 0.24899 m where the arc meets the flag's faces, or the one
  at the arc's apex x = 0.25 m: the arc lies between), the void's stiffness and the material
  (neo-Hookean and small strain against Saint Venant-Kirchhoff);
* ``report`` prints the tables of docs/benchmarks_fsi.md (each quantity, its error against
  the reference, the observed order between consecutive levels against the reference, the
  Richardson extrapolation of the three finest levels) and with ``--pictures DIR`` draws the
  flag deformed in the flow.

    python -m benchmarks.turek_hron run [--cases csm1 csm2 csm1-nh fsi1 dfg] [--levels 0 1 2 3]
    python -m benchmarks.turek_hron studies
    python -m benchmarks.turek_hron report [--pictures docs/img/benchmarks_fsi]

Outputs go to ``--output`` (default ``results/turek_hron``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "examples" / "scenes"
H0 = 0.005                              # h_min of level 0 [m]


@dataclass(frozen=True)
class Case:
    """A benchmark: its scene, the overrides that make it, its quantities and references."""

    scene: str
    title: str
    reference: dict
    overrides: tuple = ()
    source: str = "Turek & Hron (2006)"


CASES = {
    "csm1": Case("turek_hron_csm1", "CSM1, Saint Venant-Kirchhoff",
                 {"ux_A": -7.187e-3, "uy_A": -66.10e-3}),
    "csm1-nh": Case("turek_hron_csm1", "CSM1, neo-Hookean (the material's difference)",
                    {"ux_A": -7.187e-3, "uy_A": -66.10e-3}, ("structure.model=neo-hookean",)),
    "csm2": Case("turek_hron_csm2", "CSM2, Saint Venant-Kirchhoff",
                 {"ux_A": -0.469e-3, "uy_A": -16.97e-3}),
    "fsi1": Case("turek_hron_fsi1", "FSI1, Saint Venant-Kirchhoff, two-way",
                 {"ux_A": 2.2700e-5, "uy_A": 8.2090e-4, "drag": 14.295, "lift": 0.7638}),
    "dfg": Case("dfg_cylinder", "DFG 2D-1 cylinder, no structure",
                {"c_D": 5.57953523384, "c_L": 0.010618948146}, source="Schaefer & Turek (1996)"),
}
TARGETS = {("csm1", "uy_A"): 0.01, ("csm1", "ux_A"): 0.03, ("csm2", "uy_A"): 0.01, ("csm2", "ux_A"): 0.03,
           ("fsi1", "drag"): 0.01, ("fsi1", "lift"): 0.05, ("fsi1", "uy_A"): 0.03}
UNITS = {"ux_A": ("u_x(A)", 1e3, "mm"), "uy_A": ("u_y(A)", 1e3, "mm"), "drag": ("drag", 1.0, "N/m"),
         "lift": ("lift", 1.0, "N/m"), "c_D": ("c_D", 1.0, ""), "c_L": ("c_L", 1.0, "")}


# ---- the variants of the studies ---------------------------------------------------------------
def circle_fractions(mesh, circle, samples: int = 32) -> np.ndarray:
    """Each element's area fraction inside ``circle`` (midpoint rule on samples x samples points)."""
    x, y, r = circle
    P = mesh.points[mesh.quads]
    s = (np.arange(samples) + 0.5) / samples
    X = P[:, 0, 0, None, None] + (P[:, 1, 0] - P[:, 0, 0])[:, None, None] * s[None, :, None]
    Y = P[:, 0, 1, None, None] + (P[:, 3, 1] - P[:, 0, 1])[:, None, None] * s[None, None, :]
    return (((X - x) ** 2 + (Y - y) ** 2) < r * r).mean(axis=(1, 2))


def area_fraction(model, rho):
    """The circles' elements at their area fraction as density instead of the staircase's 0/1
    (the friction follows the scene's Brinkman interpolation of it)."""
    rho = rho.copy()
    for circle in model.scene.geometry.circles:
        fraction = circle_fractions(model.mesh, circle)
        cut = fraction > 0
        rho[cut] = fraction[cut]
    return rho


def off_centre_mesh(scene):
    """The scene's mesh without the circles' grid lines (the staircase no longer symmetric)."""
    from tofsi.mesh.channel import in_circle, inside
    from tofsi.mesh.grading import graded_axis
    from tofsi.mesh.structured import FLUID, SOLID, StructuredQuadMesh
    g, m = scene.geometry, scene.mesh
    boxes = [[x - r, x + r, y - r, y + r] for x, y, r in g.circles]
    features = list(g.solids) + boxes
    xs = graded_axis(g.length, [v for r in g.solids for v in r[:2]], [tuple(r[:2]) for r in features],
                     m.h_min, m.h_max, m.growth)
    ys = graded_axis(g.height, [v for r in g.solids for v in r[2:]], [tuple(r[2:]) for r in features],
                     m.h_min, m.h_max, m.growth)
    mesh = StructuredQuadMesh(xs, ys)
    region = np.full(mesh.n_elements, FLUID, dtype=np.int8)
    for circle in g.circles:
        region[in_circle(mesh.centroids, circle)] = SOLID
    for rect in g.solids:
        region[inside(mesh.centroids, rect)] = SOLID
    return mesh.with_regions(region)


@dataclass(frozen=True)
class Variant:
    """One measurement beside the benchmark: extra overrides, a mesh and densities of its own."""

    name: str
    overrides: tuple = ()
    mesh: str = ""                 # "off-centre": off_centre_mesh
    densities: str = ""            # "area-fraction", "area-fraction-linear"


ALPHAS = (1e6, 1e7, 1e8, 1e9, 1e10, 1e11)
STUDIES = {
    "alpha": [("fsi1", 1, Variant(f"alpha_max {a:.0e}", (f"fluid.alpha_max={a}",))) for a in ALPHAS]
    + [("dfg", 2, Variant(f"alpha_max {a:.0e}", (f"fluid.alpha_max={a}",))) for a in (1e4, 1e5, 1e6, 1e7, 1e8)],
    "cylinder": [("dfg", lv, v) for lv in (0, 1, 2) for v in (
        Variant("off-centre staircase", mesh="off-centre"),
        Variant("area fraction", densities="area-fraction"),
        Variant("area fraction, friction linear in it", ("design.brinkman_q=[1e6]",), densities="area-fraction"))]
    + [("fsi1", 1, Variant("off-centre staircase", mesh="off-centre"))],
    "clamp": [("csm1", lv, Variant("clamped on x = 0.25 m (the arc's apex): the flag 0.35 m long at every height",
                                   ("geometry.solids=[[0.24898979485566356, 0.25, 0.19, 0.21], [0.25, 0.6, 0.19, 0.21]]",
                                    'geometry.solid_names=["root", "flag"]',
                                    'structure.clamped=["cylinder", "root", "left", "right", "bottom", "top"]')))
              for lv in (1, 2, 3)],
    "void": [("csm1", 2, Variant("void held by the cylinder only", ('structure.clamped=["cylinder"]',))),
             ("csm1", 2, Variant("Emin / E0 = 1e-12", ("structure.e_min_ratio=1e-12",)))],
    "material": [("fsi1", 1, Variant("neo-Hookean", ("structure.model=neo-hookean",))),
                 ("fsi1", 1, Variant("small strain (linear elasticity)", ("structure.model=linear",)))],
}


# ---- one run ------------------------------------------------------------------------------------
def h_min(level: int) -> float:
    return H0 / 2 ** level


def run_one(case: str, level: int, variant: Variant | None = None) -> dict:
    """Solve one case at one level (in this process) and return its record."""
    import tofsi
    from tofsi.coupling.coupled import CoupledModel
    c = CASES[case]
    overrides = [f"mesh.h_min={h_min(level)}", *c.overrides, *(variant.overrides if variant else ())]
    scene = tofsi.load_scene(SCENES / f"{c.scene}.toml", overrides)
    load_before = os.getloadavg()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    mesh = off_centre_mesh(scene) if variant and variant.mesh == "off-centre" else None
    model = CoupledModel(scene, mesh)
    rho = model.densities()
    if variant and variant.densities:
        rho = area_fraction(model, rho)
    state = model.solve(rho)
    figures = model.figures(state)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    values = {k: figures[k] for k in c.reference if k in figures}
    if case == "dfg":
        values = {"c_D": 500 * figures["drag"], "c_L": 500 * figures["lift"]}     # the whole solid phase
    unknowns = sum(field_.size for field_ in (model.flow, model.structure) if field_ is not None)
    unknowns += 0 if model.motion is None else 2 * model.mesh.n_nodes
    return {"case": case, "level": level, "variant": variant.name if variant else "", "h_min": h_min(level),
            "elements": model.mesh.n_elements, "unknowns": int(unknowns), "values": values,
            "figures": {k: v for k, v in figures.items() if isinstance(v, (int, float))},
            "cpu_s": cpu, "wall_s": wall, "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20,
            "load": [load_before[0], os.getloadavg()[0]], "reports": {k: v for k, v in state.reports.items()
                                                                      if k in ("coupling", "structure")}}


def record_path(output: Path, case: str, level: int, variant: str = "") -> Path:
    tag = variant.replace(" ", "_").replace("/", "").replace(",", "").replace("=", "").replace("(", "").replace(")", "")
    return output / f"{case}_{level}{'_' + tag if tag else ''}.json"


def spawn(output: Path, case: str, level: int, study: str = "", index: int = -1, force: bool = False) -> dict:
    """One run in a fresh process (its own peak memory), reused when its JSON exists."""
    variant = STUDIES[study][index][2] if study else None
    path = record_path(output, case, level, variant.name if variant else "")
    if path.exists() and not force:
        return json.loads(path.read_text())
    args = [sys.executable, "-m", "benchmarks.turek_hron", "one", case, str(level), "--output", str(output)]
    if study:
        args += ["--study", study, "--index", str(index)]
    print(f"{case} level {level}{' (' + variant.name + ')' if variant else ''} ...", flush=True)
    subprocess.run(args, check=True, cwd=ROOT)
    return json.loads(path.read_text())


# ---- tables ----------------------------------------------------------------------------------------
def order(e_coarse: float, e_fine: float) -> float:
    """Observed order between consecutive levels (h halves) from errors against the reference."""
    return math.log2(abs(e_coarse) / abs(e_fine)) if e_coarse and e_fine else float("nan")


def richardson(values: list[float]) -> tuple[float, float]:
    """The limit and order from three consecutive levels (h halving), reference-free."""
    a, b, c = values
    if (b - a) * (c - b) <= 0:
        return float("nan"), float("nan")
    p = math.log2((b - a) / (c - b))
    return c + (c - b) / (2 ** p - 1), p


def table(records: list[dict], case: str) -> str:
    c = CASES[case]
    keys = list(c.reference)
    head = ["h_min [mm]", "elements", "unknowns"]
    for k in keys:
        label, _, unit = UNITS[k]
        head += [f"{label}{' [' + unit + ']' if unit else ''}", "error", "order"]
    head += ["solve CPU [s]", "solve wall [s]", "peak [GB]", "load"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    previous = None
    for r in sorted(records, key=lambda r: r["level"]):
        row = [f"{1e3 * r['h_min']:g}", f"{r['elements']:,}", f"{r['unknowns']:,}"]
        for k in keys:
            _, scale, _ = UNITS[k]
            v, ref = r["values"][k], c.reference[k]
            err = v / ref - 1
            p = order(previous["values"][k] / ref - 1, err) if previous else float("nan")
            row += [f"{scale * v:.5g}", f"{100 * err:+.2f} %", "" if math.isnan(p) else f"{p:.2f}"]
        row += [f"{r['cpu_s']:.1f}", f"{r['wall_s']:.1f}", f"{r['peak_gb']:.2f}", f"{r['load'][0]:.1f}-{r['load'][1]:.1f}"]
        lines.append("| " + " | ".join(row) + " |")
        previous = r
    ordered = sorted(records, key=lambda r: r["level"])
    if len(ordered) >= 3:
        ext = []
        for k in keys:
            limit, p = richardson([r["values"][k] for r in ordered[-3:]])
            _, scale, unit = UNITS[k]
            if math.isnan(limit) or not 0.5 <= p <= 4.0:
                ext.append(f"{UNITS[k][0]}: not in the asymptotic range" + ("" if math.isnan(p) else f" (order {p:.2f})"))
            else:
                ext.append(f"{UNITS[k][0]} {scale * limit:.5g}{' ' + unit if unit else ''} "
                           f"({100 * (limit / c.reference[k] - 1):+.2f} %, order {p:.2f})")
        lines.append("")
        lines.append("Richardson extrapolation of the three finest (reference-free): " + "; ".join(ext) + ".")
    return "\n".join(lines)


def targets(records: dict) -> str:
    lines = ["| case | quantity | target | finest mesh | met |", "|---|---|---|---|---|"]
    for (case, k), tol in TARGETS.items():
        rs = sorted(records.get(case, []), key=lambda r: r["level"])
        if not rs:
            continue
        err = rs[-1]["values"][k] / CASES[case].reference[k] - 1
        lines.append(f"| {case} | {UNITS[k][0]} | {100 * tol:g} % | {100 * err:+.2f} % (h_min {1e3 * rs[-1]['h_min']:g} mm) "
                     f"| {'yes' if abs(err) <= tol else 'no'} |")
    return "\n".join(lines)


def study_table(output: Path, study: str) -> str:
    lines = ["| case | h_min [mm] | variant | " + "quantities (error against the reference) | CPU [s] |",
             "|---|---|---|---|---|"]
    for case, level, variant in STUDIES[study]:
        for name, path in (("the benchmark scene", record_path(output, case, level)),
                           (variant.name, record_path(output, case, level, variant.name))):
            if not path.exists():
                continue
            r = json.loads(path.read_text())
            vals = ", ".join(f"{UNITS[k][0]} {UNITS[k][1] * v:.5g} ({100 * (v / CASES[case].reference[k] - 1):+.2f} %)"
                             for k, v in r["values"].items())
            lines.append(f"| {case} | {1e3 * r['h_min']:g} | {name} | {vals} | {r['cpu_s']:.0f} |")
    out = []
    for line in lines:                      # the benchmark scene once per (case, level)
        if line not in out:
            out.append(line)
    return "\n".join(out)


# ---- command line ----------------------------------------------------------------------------------
def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    one = sub.add_parser("one", help="one case at one level, in this process (what run spawns)")
    one.add_argument("case", choices=list(CASES))
    one.add_argument("level", type=int)
    one.add_argument("--study", default="")
    one.add_argument("--index", type=int, default=-1)
    run = sub.add_parser("run", help="the cases at the levels, each in a fresh process")
    run.add_argument("--cases", nargs="+", default=["csm1", "csm2", "csm1-nh", "fsi1", "dfg"], choices=list(CASES))
    run.add_argument("--levels", nargs="+", type=int, default=[0, 1, 2])
    run.add_argument("--force", action="store_true")
    studies = sub.add_parser("studies", help="the variants that measure the remaining differences")
    studies.add_argument("--studies", nargs="+", default=list(STUDIES), choices=list(STUDIES))
    studies.add_argument("--force", action="store_true")
    report = sub.add_parser("report", help="the tables of docs/benchmarks_fsi.md")
    report.add_argument("--pictures", type=Path, default=None)
    report.add_argument("--fsi-level", type=int, default=1)
    report.add_argument("--csm-level", type=int, default=2)
    for p in (one, run, studies, report):
        p.add_argument("--output", type=Path, default=Path("results/turek_hron"))
    args = parser.parse_args(argv)
    output = args.output.resolve()
    output.mkdir(parents=True, exist_ok=True)
    if args.command == "one":
        variant = STUDIES[args.study][args.index][2] if args.study else None
        record = run_one(args.case, args.level, variant)
        record_path(output, args.case, args.level, variant.name if variant else "").write_text(json.dumps(record, indent=1))
    elif args.command == "run":
        for case in args.cases:
            for level in args.levels:
                spawn(output, case, level, force=args.force)
    elif args.command == "studies":
        for study in args.studies:
            for index, (case, level, _) in enumerate(STUDIES[study]):
                spawn(output, case, level, force=args.force)
                spawn(output, case, level, study, index, force=args.force)
    else:
        records: dict = {}
        for path in sorted(output.glob("*.json")):
            r = json.loads(path.read_text())
            if not r["variant"]:
                records.setdefault(r["case"], []).append(r)
        for case, rs in records.items():
            print(f"\n### {CASES[case].title} (reference: {CASES[case].source})\n")
            print(table(rs, case))
        print("\n### Targets\n")
        print(targets(records))
        for study in STUDIES:
            print(f"\n### Study: {study}\n")
            print(study_table(output, study))
        if args.pictures:
            from benchmarks.turek_hron_pictures import pictures
            pictures(output, args.pictures, args.fsi_level, args.csm_level)


if __name__ == "__main__":
    main()
