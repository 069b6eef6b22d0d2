"""``tofsi solve SCENE``: forward analysis of the scene's design with the effects it enables.

A scene with a design region is analysed through the same design map as
``tofsi optimize``: the uniform design at the volume bound, or a saved design
(``design.initial`` or ``--design FILE``), filtered and projected with the
parameters of continuation stage ``--stage`` (default 0), so ``solve`` of a
design reproduces ``optimize``'s first iteration from it, and ``--stage N``
with the ``stage`` of a run's ``result.json`` that run's final figures
(``last``: the schedule's last stage, where a completed run ends).
"""

from __future__ import annotations

import numpy as np

from tofsi import quality
from tofsi.coupled import CoupledModel, continuation
from tofsi.errors import InputError
from tofsi.output import write_json, write_vtu
from tofsi.plotting import plot_mesh, plot_nodal
from tofsi.problem import Problem
from tofsi.provenance import solve_settings


def write_state(ctx, model: CoupledModel, state, name: str = "solution") -> None:
    """VTU (biquadratic cells: the Q2 velocity exactly) and PNG pictures of a state."""
    mesh = model.mesh
    X = mesh.points if state.x is None else mesh.points + state.mesh_displacement
    to9 = mesh.edges9                                   # Q1 fields -> Q2 nodes (bilinear)
    point_data = {}
    if state.w is not None:
        v = state.w[:model.flow.n_velocity].reshape(-1, 2)
        p = state.w[model.flow.n_velocity:]
        point_data.update(velocity=v, pressure=p[to9].mean(axis=1))
    if state.u is not None:
        point_data["structure_displacement"] = state.u.reshape(-1, 2)[to9].mean(axis=1)
    if state.x is not None:
        point_data["mesh_displacement"] = state.mesh_displacement[to9].mean(axis=1)
    cell_data = {"density": state.rho, "region": mesh.region,
                 "skewness": quality.skewness(X, mesh.quads)}
    write_vtu(ctx.path(f"{name}.vtu"), mesh.points9(X), {"quad9": mesh.quads9},
              point_data=point_data, cell_data=cell_data)
    solid = state.rho > 0.5
    if state.w is not None:
        speed = np.linalg.norm(v[: mesh.n_nodes], axis=1)
        plot_nodal(ctx.path(f"{name}_velocity.png"), X, mesh.quads, speed, grey=solid,
                   title=f"{model.scene.name}: velocity magnitude", label="|v| [m/s]")
        plot_nodal(ctx.path(f"{name}_pressure.png"), X, mesh.quads, p, grey=solid,
                   title=f"{model.scene.name}: pressure", label="p [Pa]", cmap="coolwarm")
    if state.u is not None:
        U = state.u.reshape(-1, 2)
        scale = 0.1 * np.ptp(mesh.points, axis=0).max() / max(np.abs(U).max(), 1e-300)
        scale = min(scale, 1.0) if state.x is not None else scale
        moved = mesh.points + scale * U
        plot_mesh(ctx.path(f"{name}_deformed.png"), moved, mesh.quads, state.rho,
                  title=f"{model.scene.name}: structure displacement (magnified {scale:.3g} times)",
                  label="density rho (0 fluid, 1 solid)", cmap="Greys", vmin=0, vmax=1)


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
    n_stages = d.n_stages
    stage = n_stages - 1 if stage_arg == "last" else (int(stage_arg) if stage_arg.isdigit() else -1)
    if not 0 <= stage < n_stages:
        raise InputError("--stage", stage_arg, f"allowed: 0 to {n_stages - 1} or last")
    problem = Problem(scene)                         # reads and checks design.initial
    params = continuation(scene, stage)
    problem.set_stage(beta=params.beta, penalty=params.penalty, q=params.brinkman_q, coupling=params.coupling)
    gamma = problem.initial_design()
    about = {"design": d.initial or "uniform", "stage": stage, "beta": params.beta,
             "penalty": params.penalty, "brinkman_q": params.brinkman_q}
    return problem.model, problem.densities(gamma), about, problem


def run(scene, args, ctx) -> dict:
    model, rho, about, problem = design_densities(scene, args)
    fields = ", ".join(name for name, on in (("flow", model.flow), ("structure", model.structure),
                                             ("mesh motion", model.motion)) if on is not None)
    ctx.say(f"{scene.name}: {model.mesh.n_elements} quads; solving {fields}"
            + (f" ({scene.coupled.method} two-way coupling)" if model.two_way else ""))
    if about:
        ctx.say(f"design: {about['design']} through the filter (radius {scene.design.filter_radius:g} m) "
                f"and the projection of stage {about['stage']} (beta {about['beta']:g})")
    with ctx.step(f"solving {fields} on {model.mesh.n_elements} quads"):
        state = model.solve(rho, params=None if problem is None else problem.params)
    warnings = []
    if model.structure is not None and state.x is not None:      # the mesh moved with it
        model.structure.check_displacement(state.u)
    elif model.structure is not None:                # one-way: the linear model's answer, flagged
        beyond = model.structure.displacement_beyond_channel(state.u)
        if beyond:
            warnings.append(beyond + ": the small-strain answer for a design far too soft for the "
                            "flow, not a physical state (optimize starts from it); for a designed "
                            "structure: --design FILE (the design.npy of tofsi optimize) with --stage last")
    for text in warnings:
        ctx.warn(text)
    figures = {"scene": scene.name, "converged": state.converged, **model.figures(state),
               "wall_time_s": state.reports["wall_time_s"], **about, "warnings": warnings}
    if problem is not None:
        figures["objective"] = problem.objective.value(model, state)
        figures["volume"] = problem.volume_fraction.value(model, state)
    flow = state.reports.get("flow")
    if flow:
        figures["newton_iterations"] = flow["newton_iterations"]
    for key in ("pressure_drop", "dissipated_power", "drag", "lift", "compliance", "max_displacement",
                "volume"):
        if key in figures:
            ctx.say(f"  {key.replace('_', ' '):18s} {figures[key]:.6g}")
    ctx.begin()
    with ctx.step("writing solution.vtu and pictures"):
        write_state(ctx, model, state)
    write_json(ctx.path("solve.json"), {"figures": figures, "settings": {**solve_settings(scene), **about},
                                        "reports": state.reports})
    ctx.say("wrote " + ", ".join(ctx.written))
    figures["outputs"] = list(ctx.written)
    return figures
