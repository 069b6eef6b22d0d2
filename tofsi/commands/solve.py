"""``tofsi solve SCENE``: forward analysis of the scene's design with the effects it enables."""

from __future__ import annotations

import numpy as np

from tofsi import quality
from tofsi.coupled import CoupledModel
from tofsi.output import write_json, write_vtu
from tofsi.plotting import plot_mesh, plot_nodal


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
                  title=f"{model.scene.name}: structure displacement x {scale:.3g}",
                  label="density", cmap="Greys", vmin=0, vmax=1)


def run(scene, args, ctx) -> dict:
    model = CoupledModel(scene)
    rho = model.densities()
    fields = ", ".join(name for name, on in (("flow", model.flow), ("structure", model.structure),
                                             ("mesh motion", model.motion)) if on is not None)
    ctx.say(f"{scene.name}: {model.mesh.n_elements} quads; solving {fields}"
            + (f" ({scene.coupled.method} two-way coupling)" if model.two_way else ""))
    state = model.solve(rho)
    figures = {"scene": scene.name, "converged": state.converged, **model.figures(state),
               "wall_time_s": state.reports["wall_time_s"]}
    flow = state.reports.get("flow")
    if flow:
        figures["newton_iterations"] = flow["newton_iterations"]
    for key in ("pressure_drop", "dissipated_power", "drag", "lift", "compliance", "max_displacement"):
        if key in figures:
            ctx.say(f"  {key.replace('_', ' '):18s} {figures[key]:.6g}")
    write_state(ctx, model, state)
    write_json(ctx.path("solve.json"), {"figures": figures, "reports": state.reports})
    ctx.say("wrote " + ", ".join(ctx.written))
    figures["outputs"] = list(ctx.written)
    return figures
