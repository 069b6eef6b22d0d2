"""``tofsi study SCENE --sweep KEY=START:STOP:STEP ...``: a parametric sweep to CSV and a plot.

Failed points are rows with ``status = failed`` (in the CSV, red crosses in
the plot) and are counted at the end. An interrupted study (Ctrl-C, SIGTERM)
writes the points it finished to ``study.csv`` before it stops.
"""

from __future__ import annotations

from tofsi.core.errors import InputError
from tofsi.coupling.motion import move_figures
from tofsi.runs.output import write_csv, write_json
from tofsi.runs.plotting import failed, plot_sweep
from tofsi.optimization.study import best, parse_sweep, plan, run_tasks


def runner_for(scene):
    """The function one sweep point runs: a move for mesh-motion scenes."""
    if scene.deformation.mode != "none":
        return move_figures
    raise InputError("deformation.mode", "none", "tofsi study runs mesh-motion scenes "
                     "(deformation.mode translation, rotation, bending, pressure or fsi)")


def run(scene, args, ctx) -> dict:
    if args.jobs < 1:
        raise InputError("--jobs", args.jobs, "allowed: a whole number >= 1 (worker processes)")
    sweeps = [parse_sweep(s) for s in args.sweep]
    if not sweeps:
        raise InputError("--sweep", None, "give at least one --sweep KEY=START:STOP:STEP")
    tasks = plan(scene.source, args.set, sweeps, runner_for(scene))
    keys = [s.key for s in sweeps]
    ctx.say(f"{scene.name}: {len(tasks)} runs over " + ", ".join(f"{s.key} ({len(s.values)})" for s in sweeps))
    ctx.begin()
    bar = ctx.progress(len(tasks), "study")
    rows: list[dict] = []

    def on_row(row):
        rows.append(row)
        note = "FAILED" if failed(row) else ", ".join(f"{k} = {row[k]}" for k in keys)
        bar(len(rows), len(tasks), {"note": note, **({"min_skewness": row["min_skewness"]}
                                                     if isinstance(row.get("min_skewness"), float) else {})})
    try:
        run_tasks(tasks, args.jobs, on_row)
    except KeyboardInterrupt:
        bar.close()
        write_csv(ctx.path("study.csv"), rows)          # the finished points
        ctx.say(f"interrupted: {len(rows)} of {len(tasks)} points written to {ctx.output / 'study.csv'}")
        raise
    bar.close()
    write_csv(ctx.path("study.csv"), rows)
    top = best([r for r in rows if not failed(r)])
    n_failed = sum(failed(r) for r in rows)
    write_json(ctx.path("study.json"), {"scene": scene.name, "sweeps": keys, "best": top,
                                        "failed": n_failed, "rows": rows})
    swept_mover = any(k in ("mover.name", "effects.mesh_motion") for k in keys)
    title = f"{scene.name}: " + ("" if swept_mover else f"{scene.mover.name} mover, ") + scene.deformation.mode
    if plot_sweep(ctx.path("study.png"), rows, keys, title=title) is False:
        ctx.written.pop()
    if top:
        ctx.say("best min skewness {:.4f} at ".format(top["min_skewness"])
                + ", ".join(f"{k} = {top[k]}" for k in keys))
    if n_failed:
        ctx.say(f"{n_failed} of {len(rows)} points failed (status = failed in study.csv)")
    ctx.say("wrote " + ", ".join(ctx.written))
    return {"scene": scene.name, "runs": len(rows), "failed": n_failed, "best": top,
            "outputs": list(ctx.written)}
