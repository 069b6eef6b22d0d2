"""``tofsi study SCENE --sweep KEY=START:STOP:STEP ...``: a parametric sweep to CSV and a plot."""

from __future__ import annotations

from tofsi.motion import move_figures
from tofsi.output import write_csv, write_json
from tofsi.plotting import plot_sweep
from tofsi.study import best, parse_sweep, run_study


def runner_for(scene):
    """The function one sweep point runs: a move for mesh-motion scenes."""
    if scene.deformation.mode != "none":
        return move_figures
    from tofsi.errors import InputError
    raise InputError("deformation.mode", "none", "tofsi study runs mesh-motion scenes "
                     "(deformation.mode translation, rotation, bending, pressure or fsi)")


def run(scene, args, ctx) -> dict:
    sweeps = [parse_sweep(s) for s in args.sweep]
    if not sweeps:
        from tofsi.errors import InputError
        raise InputError("--sweep", None, "give at least one --sweep KEY=START:STOP:STEP")
    total = 1
    for s in sweeps:
        total *= len(s.values)
    ctx.say(f"{scene.name}: {total} runs over " + ", ".join(f"{s.key} ({len(s.values)})" for s in sweeps))
    bar = ctx.progress(total, "study")
    rows = run_study(scene.source, args.set, sweeps, runner_for(scene), jobs=args.jobs, progress=bar)
    bar.close()
    keys = [s.key for s in sweeps]
    write_csv(ctx.path("study.csv"), rows)
    top = best(rows)
    write_json(ctx.path("study.json"), {"scene": scene.name, "sweeps": keys, "best": top, "rows": rows})
    if plot_sweep(ctx.path("study.png"), rows, keys, title=scene.name) is False:
        ctx.written.pop()
    if top:
        ctx.say("best min skewness {:.4f} at ".format(top["min_skewness"])
                + ", ".join(f"{k} = {top[k]}" for k in keys))
    ctx.say("wrote " + ", ".join(ctx.written))
    return {"scene": scene.name, "runs": len(rows), "best": top, "outputs": list(ctx.written)}
