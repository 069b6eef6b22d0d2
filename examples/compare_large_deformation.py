"""When do the mesh mover, the stiffening and a mesh-quality constraint decide a two-way design?

The large-deformation scene (``scenes/beam_in_channel_optimization_large.toml``:
a finite-strain structure that the flow moves by more than a tenth of the
channel) is optimized with every combination of

* mover: the spring analogy in increments on the updated mesh (the scene's
  ``[mover.spring]`` as shipped: 3 increments, each with its stiffness at its extrapolated
  midpoint, the first 0.1 of the motion; ``mover.spring.scheme=euler`` for the paper's),
  the spring analogy in one linear solve on the reference mesh, linear elasticity (Jacobian-stiffened), Yeoh
  hyperelastic (and, asked for by name, the spring with selective diagonals);
* stiffening: none; two layers around the fixed solid (factors 2, 1.5); two
  layers grown from the densities (the same factors, following the design);
  per-layer factors tuned by ``tofsi tune`` for the mover (on the fixed
  wall moved by the flow as far as the reference design moves: a proxy of
  the design's motion, said plainly), grown from the densities;
* the mesh-quality constraint ``design.min_skewness``: off, on.

For each run: whether it finished, the fallbacks from failed trial designs,
the smallest skewness over the two-way stages, the final design's compliance
in its own model and re-evaluated by one common reference (finite strain,
the Yeoh mover with density-grown layers, tight tolerances: the same design
judged by the same physics), the largest gap between the fluid mesh and the
structure on the solid (``max_interface_gap``, own model and reference), and
the process CPU time. Each run's row is kept in its folder (``row.json``); a
second call with the same ``--output`` takes the finished rows from there and
runs only the missing ones (``--redo`` runs them all again), and the cases
run in the order of ``--movers``, so an interrupted study keeps what ran. Beside them: the design
made with the small-strain structure, re-evaluated at finite strain; and the
design made one-way throughout, re-evaluated two-way. Writes
``large_deformation.md`` (the table), ``large_deformation.json`` and
``designs.png`` (every final design on its moved mesh) to the output folder:

    python examples/compare_large_deformation.py [--output results/compare_large_deformation] [--jobs 2]

``--mesh-size h`` runs the study on a uniform mesh of element size ``h`` [m]
instead of the scene's (the docs' table says which). ``TOFSI_EXAMPLE_SMALL=1``
runs a coarse, short version of two movers without and with density-grown
layers (the test suite does this).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import multiprocessing
import os
import time
from pathlib import Path

import numpy as np

import tofsi
from tofsi.core.blocks import State
from tofsi.coupling.coupled import continuation
from tofsi.core.errors import NumericalError
from tofsi.optimization.optimize import Optimizer
from tofsi.runs.output import write_json, write_text
from tofsi.optimization.resume import read_checkpoint
from tofsi.optimization.tuning import tune

SCENE = Path(__file__).parent / "scenes" / "beam_in_channel_optimization_large.toml"
SMALL = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.2", "optimizer.max_iter=8",
         "design.beta=[1.0, 2.0, 4.0]", 'design.coupling=["one-way", "one-way", "two-way"]',
         'design.structure_model=["linear", "linear", "neo-hookean"]', "design.stage_iterations=3",
         "structure.youngs_modulus=1e6", "tune.max_solves=6"]     # stiff: coarse gray designs hold
MOVERS = ("yeoh", "linear", "spring-1", "spring")                 # the order the cases run in
MOVER_OVERRIDES = {"yeoh": ["mover.name=yeoh"], "linear": ["mover.name=linear"],
                   "spring": ["mover.name=spring"],                # the scene's increments
                   "spring-1": ["mover.name=spring", "mover.spring.increments=1"],
                   "spring-selective": ["mover.name=spring", "mover.spring.diagonals=selective"]}
STIFFENING = {"none": ["mover.layers=[]"],
              "fixed-solid layers": ["mover.layers=[2.0, 1.5]", "mover.layers_from=solid"],
              "density-grown layers": ["mover.layers=[2.0, 1.5]", "mover.layers_from=density"],
              "tuned": None}                                # per mover, from tofsi tune
QUALITY_BOUND = 0.5
REFERENCE = ["structure.model=neo-hookean", "mover.name=yeoh", "mover.layers=[2.0, 1.5]",
             "mover.layers_from=density", "coupled.tol=1e-11", "fluid.newton_tol=1e-12"]


def small() -> list[str]:
    return SMALL if os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0" else []


SMALL_CASES = {"movers": ("yeoh", "spring"), "stiffening": ("none", "density-grown layers")}
MESH: list[str] = []     # the study's mesh, when --mesh-size replaces the scene's


def base() -> list[str]:
    """The overrides every run of the study shares: the small mode's, then the mesh's."""
    return small() + MESH


def optimize(overrides: list[str], output: Path) -> dict:
    """One optimization of the scene: its figures, the final design, the run's quality record."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    scene = tofsi.load_scene(SCENE, base() + overrides)
    problem = tofsi.Problem(scene)
    optimizer = Optimizer(problem, output)
    try:
        result = optimizer.run()
        finished, error = True, ""
    except NumericalError as err:
        finished, error, result = False, str(err).splitlines()[0], {}
    history = optimizer.history
    skew = [h.min_skewness for h in history if not math.isnan(h.min_skewness)]
    gaps = [h.max_interface_gap for h in history if not math.isnan(h.max_interface_gap)]
    last_good = output / "design.npy"            # written after every design that solved
    gamma = np.load(last_good) if last_good.exists() else None
    return {"finished": finished, "error": error, "fallbacks": optimizer.fallbacks,
            "iterations": len(history), "min_skewness_over_run": min(skew) if skew else float("nan"),
            "compliance": result.get("objective", float("nan")),
            "max_displacement": result.get("max_displacement", float("nan")),
            "max_solid_displacement": result.get("max_solid_displacement", float("nan")),
            "final_min_skewness": result.get("min_skewness", float("nan")),
            "max_interface_gap": result.get("max_interface_gap", float("nan")),
            "max_interface_gap_over_run": max(gaps) if gaps else float("nan"),
            "wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - cpu0,
            "design": None if gamma is None else gamma.tolist()}


def last_state(folder: Path) -> State | None:
    """The last coupled state a run in ``folder`` computed (its checkpoint), or None."""
    path = folder / "checkpoint.npz"
    if not path.exists():
        return None
    _, data = read_checkpoint(path)
    return State(rho=data["rho"], converged=True,
                 fields={k[len("state_"):]: v for k, v in data.items() if k.startswith("state_")})


def reference(gamma, folder: Path | None = None) -> tuple[float, float, float, str]:
    """``(compliance [J/m], largest displacement of the solid [m], interface gap [m], "")`` of
    design ``gamma`` judged by the common reference (finite strain, Yeoh, density-grown layers,
    tight tolerances) at the schedule's last stage; ``(NaN, NaN, NaN, why)`` if its solve fails.

    The solve starts from the last state of the run that made the design (``folder``): at
    this motion the coupled problem has more than one solution, and the inflow ramped from
    rest can fold the mesh on the way (measured: the reference run's own final design folds
    an element at 0.21 of the inflow when ramped cold, and solves from its run's state)."""
    scene = tofsi.load_scene(SCENE, base() + REFERENCE)
    problem = tofsi.Problem(scene)
    problem.set_stage(continuation(scene, scene.design.n_stages - 1))
    if folder is not None:
        problem.set_guess(last_state(folder))
    try:
        state = problem.solve(np.asarray(gamma, dtype=float))
    except NumericalError as err:
        return float("nan"), float("nan"), float("nan"), str(err)
    figures = problem.model.figures(state)
    return (problem.objective.value(problem.model, state), figures["max_solid_displacement"],
            figures["max_interface_gap"], "")


def tuned_layers(mover: str, motion: float) -> list[float]:
    """Per-layer stiffening factors tuned by ``tofsi tune`` for ``mover`` on the fixed wall moved
    by the flow (``deformation.mode = "fsi"``) to ``motion`` [m]."""
    scene = tofsi.load_scene(SCENE, base() + [*MOVER_OVERRIDES[mover], "geometry.design=[]",
                                               "design.coupling=[]", "deformation.mode=fsi",
                                               f"deformation.tip_displacement={motion:g}",
                                               "tune.layers=4", "tune.max_solves=24"])
    return [float(f) for f in tune(scene).layer_factors]


def case(job) -> dict:
    mover, stiffening, constraint, layers, output, mesh, redo = job
    MESH[:] = mesh                                  # a spawned worker starts from the module's empty list
    folder = case_folder(output, mover, stiffening, constraint)
    kept = folder / "row.json"
    if kept.exists() and not redo:                  # a finished case of an earlier call
        return {**json.loads(kept.read_text()), "kept": True}
    overrides = [*MOVER_OVERRIDES[mover], *(STIFFENING[stiffening] or
                                            [f"mover.layers={layers}", "mover.layers_from=density"])]
    if constraint:
        overrides.append(f"design.min_skewness={QUALITY_BOUND}")
    row = {"mover": mover, "stiffening": stiffening, "constraint": constraint, **optimize(overrides, folder)}
    judge(row, folder)
    write_json(kept, row)
    return row


def judge(row: dict, folder: Path) -> None:
    """The reference's compliance, solid displacement and interface gap of a row's design (NaN
    without one)."""
    (row["reference_compliance"], row["reference_solid_displacement"], row["reference_interface_gap"],
     row["reference_error"]) = (reference(row["design"], folder) if row["design"] is not None
                                else (float("nan"),) * 3 + ("no design",))


def case_folder(output: Path, mover: str, stiffening: str, constraint: bool) -> Path:
    return output / f"{mover}-{stiffening.split()[0]}-{'q' if constraint else 'free'}"


def short(error: str) -> str:
    """A failed run's message cut to where, and the cause's last clause."""
    where = error.split(":")[0]
    return f"{where}: ...{error[-90:]}" if len(error) > 100 else error


def table(rows: list[dict], extra: dict) -> str:
    lines = [("| mover | stiffening | quality constraint | finished | fallbacks | min skewness over the run | "
             "final min skewness | compliance, own model [J/m] | compliance, reference [J/m] | "
             "solid's largest displacement, reference [m] | interface gap, own / reference [mm] | CPU time [s] |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mover']} | {r['stiffening']} | {'on' if r['constraint'] else 'off'} | "
                     f"{'yes' if r['finished'] else 'no: ' + short(r['error'])} | {r['fallbacks']} | "
                     f"{r['min_skewness_over_run']:.3f} | {r['final_min_skewness']:.3f} | {r['compliance']:.4g} | "
                     f"{r['reference_compliance']:.4g} | {r['reference_solid_displacement']:.3g} | "
                     f"{1e3 * r['max_interface_gap']:.2g} / {1e3 * r['reference_interface_gap']:.2g} | "
                     f"{r['cpu_time_s']:.0f} |")
    lines += ["", "| design | own model [J/m] | re-evaluated [J/m] | by |", "|---|---|---|---|"]
    lines += [f"| {name} | {e['own']:.4g}{' (failed: ' + short(e['error']) + ')' if e.get('error') else ''} | "
              f"{e['reference']:.4g}{' (' + short(e['reference_error']) + ')' if e.get('reference_error') else ''} | "
              f"{e['by']} |" for name, e in extra.items()]
    return "\n".join(lines) + "\n"


def pictures(rows: list[dict], path: Path) -> None:
    """Every finished run's final density, side by side (movers across, the other choices down)."""
    import matplotlib.pyplot as plt

    from tofsi.runs.plotting import save
    scene = tofsi.load_scene(SCENE, base())
    problem = tofsi.Problem(scene)
    problem.set_stage(continuation(scene, scene.design.n_stages - 1))
    mesh = problem.model.mesh
    variants = sorted({(r["stiffening"], r["constraint"]) for r in rows})
    names = list(dict.fromkeys(r["mover"] for r in rows))
    fig, axes = plt.subplots(len(variants), len(names), figsize=(3.2 * len(names), 1.9 * len(variants)),
                             squeeze=False, layout="constrained")
    for ax in axes.flat:                    # a mover x variant without a run stays blank
        ax.set_axis_off()
    for r in rows:
        ax = axes[variants.index((r["stiffening"], r["constraint"])), names.index(r["mover"])]
        ax.set_axis_on()
        if r["design"] is not None:         # a failed run: its last design that solved
            rho = problem.densities(np.asarray(r["design"]))
            ax.tripcolor(mesh.points[:, 0], mesh.points[:, 1],
                         np.vstack([mesh.quads[:, [0, 1, 2]], mesh.quads[:, [0, 2, 3]]]),
                         facecolors=np.concatenate([rho, rho]), cmap="Greys", vmin=0, vmax=1)
        ax.set_title(f"{r['mover']}, {r['stiffening']}, q {'on' if r['constraint'] else 'off'}: "
                     + (f"{r['reference_compliance']:.3g} J/m" if math.isfinite(r["reference_compliance"])
                        else f"{r['compliance']:.3g} J/m own (no reference)")
                     + ("" if r["finished"] else " (failed)"), fontsize=7)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    save(fig, path)


def kept_or_run(path: Path, run, redo: bool):
    """The JSON record at ``path`` if an earlier call left one (and not ``redo``), else ``run()``'s,
    written there."""
    if path.exists() and not redo:
        return json.loads(path.read_text())
    record = run()
    write_json(path, record)
    return record


def main(output: Path, jobs: int = 1, movers=MOVERS, stiffening=tuple(STIFFENING), mesh_size=None,
         redo: bool = False, extras_too: bool = True) -> dict:
    output.mkdir(parents=True, exist_ok=True)
    if mesh_size is not None:
        MESH[:] = [f"mesh.h_min={mesh_size:g}", f"mesh.h_max={mesh_size:g}"]
        print(f"the study's mesh: uniform, element size {mesh_size:g} m", flush=True)
    reference_run, layers = {}, {}
    if "tuned" in stiffening:                       # the motion the tuning aims at
        print("reference run (for the tuning's motion): yeoh, density-grown layers, no constraint", flush=True)
        reference_run = kept_or_run(output / "reference" / "row.json",
                                    lambda: optimize(["mover.name=yeoh"], output / "reference"), redo)
        motion = reference_run["max_solid_displacement"] if reference_run["finished"] else 0.1
        layers = {m: kept_or_run(output / f"tuned-{m}.json", lambda m=m: tuned_layers(m, motion), redo)
                  for m in movers}
    for m, f in layers.items():
        print(f"tuned layers for {m}: {[round(v, 3) for v in f]}", flush=True)
    jobs_list = [(m, s, c, layers.get(m), output, list(MESH), redo)
                 for m, s, c in itertools.product(movers, stiffening, (False, True))]
    with multiprocessing.get_context("spawn").Pool(jobs) as pool:
        rows = []
        for row in pool.imap(case, jobs_list):
            print(f"  {row['mover']:16s} {row['stiffening']:22s} q {'on ' if row['constraint'] else 'off'}: "
                  f"{'finished' if row['finished'] else 'FAILED'}, fallbacks {row['fallbacks']}, min skewness "
                  f"{row['min_skewness_over_run']:.3f}, gap {row['max_interface_gap']:.2g} m, reference compliance "
                  f"{row['reference_compliance']:.4g}, {row['cpu_time_s']:.0f} s CPU"
                  + (" (kept from an earlier call)" if row.pop("kept", False) else ""), flush=True)
            rows.append(row)
            report(output, rows, {}, layers, reference_run, pictures_too=False)   # the table so far
    extra = extras(output, redo) if extras_too else {}
    report(output, rows, extra, layers, reference_run)
    return {"rows": rows, "extra": extra}


EXTRA = {"small-strain structure": (["structure.model=linear", "design.structure_model=[]"], "finite strain",
                                    "small-strain"),
         "one-way throughout": (['design.coupling=["one-way"]'], "two-way", "one-way")}


def extras(output: Path, redo: bool = False) -> dict:
    """The small-strain design and the one-way design, each judged by the reference."""
    out = {}
    for name, (overrides, by, folder) in EXTRA.items():
        def run_and_judge(overrides=overrides, folder=folder, by=by):
            run = optimize(["mover.name=yeoh", *overrides], output / folder)
            judged = (reference(run["design"], output / folder) if run["design"] is not None
                      else (0, 0, 0, "no design"))
            return {"own": run["compliance"], "by": by, "reference": judged[0], "error": run["error"],
                    "reference_error": judged[3]}
        out[name] = kept_or_run(output / folder / "row.json", run_and_judge, redo)
        print(f"  {name}: own {out[name]['own']:.4g}, by the reference {out[name]['reference']:.4g}", flush=True)
    return out


def rescore(output: Path, redo_extras: bool = False) -> None:
    """Judge the designs of a finished study in ``output`` by the reference again (after a change
    of the reference), from their runs' folders, and rewrite the report; ``redo_extras``: run
    the small-strain and one-way designs again first (after a change of their settings)."""
    record = json.loads((output / "large_deformation.json").read_text())
    nan = float("nan")                                   # written as null
    record["rows"] = [{k: nan if v is None and k != "design" else v for k, v in r.items()} for r in record["rows"]]
    record["extra"] = {n: {k: nan if v is None else v for k, v in e.items()} for n, e in record["extra"].items()}
    for r in record["rows"]:
        judge(r, case_folder(output, r["mover"], r["stiffening"], r["constraint"]))
    if redo_extras:
        record["extra"] = extras(output)
    else:
        for name, e in record["extra"].items():
            folder = output / EXTRA[name][2]
            e["reference"], _, _, e["reference_error"] = reference(np.load(folder / "design.npy"), folder)
    report(output, record["rows"], record["extra"], record["tuned_layers"], record["reference"])


def report(output: Path, rows, extra, layers, reference, pictures_too: bool = True) -> None:
    """``large_deformation.md`` (the table), ``.json`` and ``designs.png`` in ``output``."""
    mesh = MESH[0].split("=")[1] + " m (--mesh-size)" if MESH else "the scene's"
    text = f"Mesh: {mesh}; small mode: {bool(small())}.\n\n" + table(rows, extra)
    write_text(output / "large_deformation.md", text)
    write_json(output / "large_deformation.json", {"rows": rows, "extra": extra, "tuned_layers": layers,
                                                   "reference": reference})
    if pictures_too:
        pictures(rows, output / "designs.png")
        print(text)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("results/compare_large_deformation"))
    parser.add_argument("--jobs", type=int, default=1, help="optimizations run at once")
    parser.add_argument("--movers", nargs="+", default=list(MOVERS), choices=list(MOVER_OVERRIDES),
                        help="the movers, in the order their cases run")
    parser.add_argument("--redo", action="store_true", help="run the cases whose rows --output holds again")
    parser.add_argument("--no-extras", action="store_true",
                        help="skip the small-strain and one-way controls")
    parser.add_argument("--stiffening", nargs="+", default=list(STIFFENING), choices=list(STIFFENING))
    parser.add_argument("--rescore", action="store_true",
                        help="judge the designs of the study in --output by the reference again")
    parser.add_argument("--redo-extras", action="store_true",
                        help="with --rescore: run the small-strain and one-way designs again")
    parser.add_argument("--mesh-size", type=float, default=None,
                        help="uniform element size [m] of the study (default: the scene's mesh)")
    args = parser.parse_args()
    if small():
        print("small mode (TOFSI_EXAMPLE_SMALL): " + ", ".join(SMALL) + f"; movers {SMALL_CASES['movers']}, "
              f"stiffening {SMALL_CASES['stiffening']} -- Young's modulus raised from 1.5 kPa to 1 MPa so the "
              "coarse gray designs hold")
        args.movers, args.stiffening = SMALL_CASES["movers"], SMALL_CASES["stiffening"]
    if args.rescore:
        MESH[:] = [] if args.mesh_size is None else [f"mesh.h_min={args.mesh_size:g}", f"mesh.h_max={args.mesh_size:g}"]
        rescore(args.output, args.redo_extras)
    else:
        main(args.output, args.jobs, tuple(args.movers), tuple(args.stiffening), args.mesh_size, args.redo,
             not args.no_extras)
