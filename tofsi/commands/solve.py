"""``tofsi solve SCENE``: forward analysis of the scene's design with the effects it enables.

A scene with a design region is analysed through the same design map as
``tofsi optimize``: the uniform design at the volume bound, or a saved design
(``design.initial`` or ``--design FILE``), filtered and projected with the
parameters of continuation stage ``--stage`` (default 0), so ``solve`` of a
design reproduces ``optimize``'s first iteration from it, and ``--stage N``
with the ``stage`` of a run's ``result.json`` that run's final figures
(``last``: the schedule's last stage, where a completed run ends).

A one-way state whose small-strain displacement exceeds the channel (a gray
design far too soft for the flow: optimize's iteration 0 of a soft scene) is no
physical state: its figures and pictures are written with ``physical: false``
and a warning, and the exit status is 5, unless ``--allow-unphysical`` accepts
them (exit 0, the warning kept). Where the mesh moves with the structure
(two-way) such a displacement is a numerical failure (exit 3).
"""

from __future__ import annotations


from tofsi.mesh import quality
from tofsi.commands.context import stage_index
from tofsi.coupling.coupled import CoupledModel, continuation
from tofsi.core.errors import InputError
from tofsi.fields.base import Picture, state_points
from tofsi.runs.output import write_json, write_vtu
from tofsi.runs.plotting import plot_mesh, plot_nodal, region_outlines
from tofsi.optimization.problem import Problem
from tofsi.runs.provenance import solve_settings


UNPHYSICAL = 5      # exit status: the figures are written, but they are no physical state


def write_state(ctx, model: CoupledModel, state, name: str = "solution") -> None:
    """VTU (biquadratic cells: the Q2 velocity exactly) with every active field's arrays, and
    the pictures each field asks for (:meth:`tofsi.fields.base.Field.pictures`)."""
    mesh = model.mesh
    X = state_points(model, state)
    point_data = {}
    for field in model.fields:
        point_data.update(field.point_data(model, state))
    cell_data = {"density": state.rho, "region": mesh.region, "skewness": quality.skewness(X, mesh.quads)}
    write_vtu(ctx.path(f"{name}.vtu"), mesh.points9(X), {"quad9": mesh.quads9},
              point_data=point_data, cell_data=cell_data)
    for field in model.fields:
        for picture in field.pictures(model, state):
            draw(ctx.path(f"{name}_{picture.name}.png"), picture, X, mesh, state.rho,
                 f"{model.scene.name}: {picture.title}")


def draw(path, picture: Picture, X, mesh, rho, title: str) -> None:
    """A field's picture: nodal values on the mesh at ``X`` (solid greyed), or a mesh coloured
    per element; the design region and the fixed solid outlined over either."""
    outlines = region_outlines(mesh.quads, mesh.region)
    if picture.kind == "nodal":
        plot_nodal(path, X, mesh.quads, picture.values, grey=rho > 0.5, title=title, label=picture.label,
                   cmap=picture.cmap, outlines=outlines)
    else:
        plot_mesh(path, picture.points, mesh.quads, picture.values, title=title, label=picture.label,
                  cmap=picture.cmap, vmin=picture.vmin, vmax=picture.vmax, outlines=outlines)


def design_densities(scene, args):
    """``(model, rho, about, problem)``: the scene's design -- uniform, ``design.initial`` or
    ``--design`` -- through the filter and projection of continuation stage ``--stage``, as
    ``optimize`` maps it; scenes without a design region use their fixed densities (no problem)."""
    stage_arg = str(getattr(args, "stage", "0"))
    if not scene.has_design:
        if scene.design.initial:
            raise InputError("design.initial", scene.design.initial,
                             "the scene has no design region (geometry.design) to apply a design to")
        if stage_arg != "0":
            raise InputError("--stage", stage_arg, "the scene has no design region (geometry.design)")
        model = CoupledModel(scene)
        return model, model.densities(), {}, None
    d = scene.design
    stage = stage_index(scene, stage_arg)
    problem = Problem(scene)                         # reads and checks design.initial
    params = continuation(scene, stage)
    problem.set_stage(params)
    gamma = problem.initial_design()
    about = {"design": d.initial or "uniform", "stage": stage, "beta": params.beta,
             "penalty": params.penalty, "brinkman_q": params.brinkman_q}
    return problem.model, problem.densities(gamma), about, problem


def run(scene, args, ctx) -> dict:
    model, rho, about, problem = design_densities(scene, args)
    fields = ", ".join(field.title for field in model.fields)
    ctx.say(f"{scene.name}: {model.mesh.n_elements} quads; solving {fields}"
            + (f" ({scene.coupled.method} two-way coupling)" if model.two_way else ""))
    if about:
        ctx.say(f"design: {about['design']} through the filter (radius {scene.design.filter_radius:g} m) "
                f"and the projection of stage {about['stage']} (beta {about['beta']:g})")
    with ctx.step(f"solving {fields} on {model.mesh.n_elements} quads"):
        state = model.solve(rho, params=None if problem is None else problem.params)
    hint = ("; for a designed structure: --design FILE (the design.npy of tofsi optimize) with --stage last"
            + ("" if args.allow_unphysical else f"; exit status {UNPHYSICAL} (--allow-unphysical accepts "
                                                 "these figures)"))
    warnings = [text + hint for field in model.fields for text in field.check(model, state)]
    physical = not warnings
    for text in warnings:
        ctx.warn(text)
    if not physical and not args.allow_unphysical:
        ctx.exit_status = UNPHYSICAL
    figures = {"scene": scene.name, "converged": state.converged, "physical": physical, **model.figures(state),
               "wall_time_s": state.reports["wall_time_s"], **about, "warnings": warnings}
    if problem is not None:
        figures["objective"] = problem.objective.value(model, state)
        figures["volume"] = problem.volume_fraction.value(model, state)
    flow = state.reports.get("flow")
    if flow:
        figures["newton_iterations"] = flow["newton_iterations"]
    for key in [k for field in model.fields for k in field.summary] + ["objective", "volume"]:
        if key in figures:
            ctx.say(f"  {key.replace('_', ' '):22s} {figures[key]:.6g}")
    ctx.begin()
    with ctx.step("writing solution.vtu and pictures"):
        write_state(ctx, model, state)
    write_json(ctx.path("solve.json"), {"figures": figures, "settings": {**solve_settings(model), **about},
                                        "reports": state.reports})
    ctx.say("wrote " + ", ".join(ctx.written))
    figures["outputs"] = list(ctx.written)
    return figures
