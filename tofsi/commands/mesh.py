"""``tofsi mesh SCENE``: build the mesh, print its sizes, write VTU and PNG."""

from __future__ import annotations

import numpy as np

from tofsi.mesh import quality
from tofsi.mesh.channel import build_mesh
from tofsi.mesh.layers import element_layers
from tofsi.mesh.structured import REGION_NAMES, SOLID
from tofsi.runs.output import write_vtu
from tofsi.runs.plotting import plot_mesh, region_outlines


def mesh_figures(mesh) -> dict:
    h = mesh.element_sizes
    return {"n_nodes": mesh.n_nodes, "n_elements": mesh.n_elements, "nx": mesh.nx, "ny": mesh.ny,
            "n_nodes_q2": mesh.n_nodes9,
            "regions": {REGION_NAMES[r]: int(np.sum(mesh.region == r)) for r in REGION_NAMES},
            "n_interface_nodes": int(mesh.interface_nodes.size),
            "h_smallest": float(h.min()), "h_largest": float(h.max()),
            "max_aspect_ratio": float(np.max(h.max(axis=1) / h.min(axis=1)))}


def run(scene, args, ctx) -> dict:
    mesh = build_mesh(scene.geometry, scene.mesh)
    figures = {"scene": scene.name, **mesh_figures(mesh)}
    ctx.say(f"{scene.name}: {mesh.nx} x {mesh.ny} = {mesh.n_elements} quads, {mesh.n_nodes} nodes "
            f"(Q2 velocity mesh: {mesh.n_nodes9} nodes)")
    ctx.say("regions: " + ", ".join(f"{k} {v}" for k, v in figures["regions"].items())
            + f"; element size {figures['h_smallest']:.4g} to {figures['h_largest']:.4g} m")
    layer = element_layers(mesh.incidence, mesh.interface_nodes, mesh.region != SOLID)
    skew = quality.skewness(mesh.points, mesh.quads)
    ctx.begin()
    write_vtu(ctx.path("mesh.vtu"), mesh.points, {"quad": mesh.quads},
              cell_data={"region": mesh.region, "layer": layer, "skewness": skew,
                         "area": quality.signed_area(mesh.points, mesh.quads)})
    design = [o for o in region_outlines(mesh.quads, mesh.region) if o.label == "design region"]
    plot_mesh(ctx.path("mesh.png"), mesh.points, mesh.quads, layer, mesh.interface_edges,
              title=f"{scene.name}: {mesh.nx} x {mesh.ny} = {mesh.n_elements} quads",
              label="element layer counted from the interface (1: touching it)",
              grey=mesh.region == SOLID, cmap="viridis_r", outlines=design)
    ctx.say("wrote " + ", ".join(ctx.written))
    figures["outputs"] = list(ctx.written)
    return figures
