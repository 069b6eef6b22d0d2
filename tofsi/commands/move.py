"""``tofsi move SCENE``: apply the scene's structure motion with its mover; report quality."""

from __future__ import annotations

import numpy as np

from tofsi.mesh import quality
from tofsi.core.errors import InputError, NumericalError
from tofsi.mesh.structured import SOLID
from tofsi.coupling.motion import motion_setup, moved_quality, run_move
from tofsi.runs.output import write_json, write_vtu
from tofsi.runs.plotting import Outline, element_boundary, plot_mesh
from tofsi.runs.provenance import mover_settings

MOTION_KEYS = {"translation": "deformation.translation", "rotation": "deformation.rotation_deg",
               "bending": "deformation.bending_tip", "pressure": "deformation.tip_displacement",
               "fsi": "deformation.tip_displacement"}


def check_motion_inside(scene, setup) -> None:
    """Before moving: every solid node that starts inside the channel must stay strictly
    inside it (a solid pushed onto or through a wall leaves no room for the fluid mesh)."""
    mesh, g = setup.mesh, scene.geometry
    nodes = mesh.nodes_of(SOLID)
    start = mesh.points[nodes]
    moved = start + setup.prescribed[nodes]
    size = np.array([g.length, g.height])
    tol = 1e-12 * size
    interior = (start > tol) & (start < size - tol)             # per coordinate
    outside = interior & ((moved <= tol) | (moved >= size - tol))
    if outside.any():
        k = int(np.flatnonzero(outside.any(axis=1))[0])
        d = scene.deformation
        key = MOTION_KEYS[d.mode] if (d.mode != "fsi" or d.scale) else "deformation.mode"
        value = getattr(d, key.split(".")[1])
        raise InputError(key, value, f"moves the solid out of the channel: the solid node at "
                         f"({start[k, 0]:.4g}, {start[k, 1]:.4g}) goes to ({moved[k, 0]:.4g}, "
                         f"{moved[k, 1]:.4g}), outside (0, {g.length:g}) x (0, {g.height:g}); "
                         "use a smaller motion")


def write_moved_mesh(ctx, setup, displacement, name, title, cell_data=None, broken=None):
    """VTU and picture of the mesh moved by ``displacement``; inverted elements outlined, and
    ``broken`` (a mover diagnostic's ``broken_element``: the element a failed step inverts)."""
    mesh = setup.mesh
    moved = mesh.points + displacement
    skew = quality.skewness(moved, mesh.quads)
    data = {"region": mesh.region, "layer": setup.layer, "skewness": skew,
            "area_change": quality.area_change(mesh.points, moved, mesh.quads)}
    for key, values in (cell_data or {}).items():          # per moving quad -> per element
        full = np.full(mesh.n_elements, -1.0)
        full[setup.moving] = values
        data[key] = full
    write_vtu(ctx.path(f"{name}.vtu"), moved, {"quad": mesh.quads},
              point_data={"displacement": displacement}, cell_data=data)
    inverted = quality.inverted(moved, mesh.quads) & (mesh.region != SOLID)
    outlines = [Outline(element_boundary(mesh.quads, inverted), f"inverted element ({int(inverted.sum())})",
                        "black", width=1.6)] if inverted.any() else []
    if broken is not None:
        k = broken["element"]
        outlines.append(Outline(element_boundary(mesh.quads, np.arange(mesh.n_elements) == k),
                                f"element {k}: inverted by the failed step", "magenta", width=2.0))
    plot_mesh(ctx.path(f"{name}.png"), moved, mesh.quads, skew, mesh.interface_edges, title=title,
              vmin=min(0.0, float(skew.min())), vmax=1.0, grey=mesh.region == SOLID, cmap="RdYlGn",
              outlines=outlines)


def run(scene, args, ctx) -> dict:
    setup = motion_setup(scene)
    check_motion_inside(scene, setup)
    ctx.say(f"{scene.name}: moving {setup.moving.size} quads with the {scene.mover.name} mover "
            f"({scene.deformation.mode}); stiffening layers {list(scene.mover.layers) or 'none'}")
    bar = ctx.progress(1, f"{scene.mover.name} mover", every=1.0)
    try:
        _, result = run_move(scene, progress=bar, setup=setup)
    except NumericalError as err:
        bar.close()
        ctx.begin()
        state = getattr(err, "state", None)
        if state is not None:
            write_moved_mesh(ctx, setup, state, "failed_mesh", f"{scene.name}: FAILED ({err})",
                             broken=err.diagnostic.get("broken_element"))
        raise
    bar.close()
    q = moved_quality(setup, result.displacement)
    r = result.report
    figures = {"scene": scene.name, "mover": scene.mover.name, "mode": scene.deformation.mode,
               "converged": r.converged, "min_skewness": q.min_skewness,
               "min_area_change": q.min_area_change, "max_area_change": q.max_area_change,
               "n_inverted": q.n_inverted, "worst_element": q.min_skewness_element,
               "worst_location": list(q.min_skewness_location), "wall_time_s": r.wall_time_s,
               "increments": r.increments, "newton_iterations": r.newton_iterations,
               "linear_solves": r.linear_solves, "factorizations": r.factorizations,
               "cutbacks": r.cutbacks, "n_moving_elements": int(setup.moving.size)}
    ctx.say(f"min skewness {q.min_skewness:.4f} (element {q.min_skewness_element} at "
            f"({q.min_skewness_location[0]:.3f}, {q.min_skewness_location[1]:.3f})), area change "
            f"{q.min_area_change:.4f} to {q.max_area_change:.4f}, {q.n_inverted} inverted; "
            f"{r.increments} increments, {r.newton_iterations} Newton iterations, "
            f"{r.wall_time_s:.2f} s")
    ctx.begin()
    write_moved_mesh(ctx, setup, result.displacement, "moved_mesh",
                     f"{scene.name} ({scene.deformation.mode}), {scene.mover.name}: "
                     f"min skewness {q.min_skewness:.3f}", result.cell_data)
    write_json(ctx.path("move.json"), {"figures": figures, "settings": mover_settings(scene),
                                     "report": r.as_dict()})
    ctx.say("wrote " + ", ".join(ctx.written))
    figures["outputs"] = list(ctx.written)
    return figures
