"""``tofsi tune SCENE``: stiffening factors tuned by gradients for the scene's motion and mover.

Settings come from the scene's ``[tune]`` table (``--set tune.layers=4``,
``--set tune.parametrization=profile``, ...; see :mod:`tofsi.optimization.tuning`).
Writes ``tune.json`` (figures, the tuned design and every evaluation),
``tune_history.csv``, and the mesh moved with the tuned factors
(``tuned_mesh.vtu`` / ``.png``).
"""

from __future__ import annotations

from tofsi.commands.move import check_motion_inside, write_moved_mesh
from tofsi.coupling.motion import motion_setup
from tofsi.runs.output import write_csv, write_json
from tofsi.runs.provenance import mover_settings, scene_tables
from tofsi.optimization.tuning import tune


def run(scene, args, ctx) -> dict:
    s = scene.tune
    setup = motion_setup(scene)
    check_motion_inside(scene, setup)
    what = (f"{s.layers} layer factors" if s.parametrization == "layers"
            else "a decaying factor profile (amplitude, decay length)")
    ctx.say(f"{scene.name}: tuning {what} of the {scene.mover.name} mover ({scene.deformation.mode}) "
            f"on {setup.moving.size} quads; KS soft minimum of the corner skewness, p = {', '.join(f'{p:g}' for p in s.ks)}; "
            f"NLopt {s.algorithm}, at most {s.max_solves} mover solves (moves and adjoints)")
    bar = ctx.progress(s.max_solves, "tune")
    try:
        result = tune(scene, progress=bar, setup=setup)
    finally:
        bar.close()
    figures = {"scene": scene.name, "mover": scene.mover.name, "mode": scene.deformation.mode,
               **result.figures(), "ks": list(s.ks), "algorithm": s.algorithm}
    factors = ", ".join(f"{f:.3g}" for f in result.layer_factors)
    ctx.say(f"tuned factors [{factors}]: min skewness {result.min_skewness:.4f} (soft minimum "
            f"{result.soft_min_skewness:.4f}), area change {result.min_area_change:.4f} to "
            f"{result.max_area_change:.4f}, {result.n_inverted} inverted; {result.moves} moves "
            f"+ {result.adjoints} adjoint solves, {result.wall_time_s:.1f} s ({result.stop})")
    if s.parametrization == "layers":
        ctx.say(f"use them with --set mover.layers=[{factors}]")
    ctx.begin()
    best = result.best
    stiffening = {"stiffening": best.problem.stiffening}
    write_moved_mesh(ctx, setup, best.result.displacement, "tuned_mesh",
                     f"{scene.name}, {scene.mover.name}, tuned: min skewness {result.min_skewness:.3f}",
                     {**best.result.cell_data, **stiffening})
    write_csv(ctx.path("tune_history.csv"),
              [{"evaluation": i + 1, **{k: v for k, v in row.items() if k != "factors"},
                **{f"factor_{k + 1}": f for k, f in enumerate(row["factors"])}}
               for i, row in enumerate(result.history)])
    write_json(ctx.path("tune.json"), {"figures": figures, "settings": {**mover_settings(scene),
                                                                      "tune": scene_tables(scene)["tune"]},
                                     "history": result.history})
    ctx.say("wrote " + ", ".join(ctx.written))
    figures["outputs"] = list(ctx.written)
    return figures
