"""The figures a scene's ``[probes]`` table asks for: displacements at points, forces on solids.

* ``probes.points = [[x, y]]``, ``probes.point_names = ["A"]``: the structure's displacement at each point,
  ``ux_A`` and ``uy_A`` [m], bilinear on the reference element holding the point
  (exact at a node: a point on grid lines, as Turek & Hron's A on the flag's
  tip, is a node's value);
* ``probes.forces = ["cylinder", "flag"]``: the fluid's force on each named solid,
  ``drag_<name>`` and ``lift_<name>`` [N/m], the sum of the fluid load's element
  contributions over the solid's elements (the momentum-consistent reaction by
  default, whose resultant over a body tends to its no-slip drag and lift; the
  whole solid phase's is the flow's ``drag`` and ``lift``).
"""

from __future__ import annotations

import numpy as np

from tofsi.mesh.channel import named_solids


def interpolate(mesh, values: np.ndarray, point) -> np.ndarray:
    """Nodal ``values`` ``(n, k)`` at ``point`` (x, y) on the reference tensor grid (bilinear in
    the element holding it; the last element of a row or column at the channel's far sides)."""
    x, y = point
    i = int(np.clip(np.searchsorted(mesh.xs, x, side="right") - 1, 0, mesh.nx - 1))
    j = int(np.clip(np.searchsorted(mesh.ys, y, side="right") - 1, 0, mesh.ny - 1))
    s = (x - mesh.xs[i]) / (mesh.xs[i + 1] - mesh.xs[i])
    t = (y - mesh.ys[j]) / (mesh.ys[j + 1] - mesh.ys[j])
    corners = mesh.quads[j * mesh.nx + i]
    weights = np.array([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t])
    return weights @ np.asarray(values)[corners]


def probe_figures(model, state) -> dict:
    """``ux_<point>``, ``uy_<point>`` (with a structure) and ``drag_<solid>``, ``lift_<solid>``
    (with a flow) of a coupled state [m, N/m]."""
    probes = model.scene.probes
    out = {}
    if state.u is not None:
        U = state.u.reshape(-1, 2)
        for name, point in probes.named_points.items():
            out[f"ux_{name}"], out[f"uy_{name}"] = (float(v) for v in interpolate(model.mesh, U, point))
    if probes.forces and model.force is not None and state.w is not None:
        fe = model.force.elements(state.w, state.mesh_displacement, state.rho, state.params)[0]
        solids = named_solids(model.scene.geometry, model.mesh)
        for name in probes.forces:
            elements = solids[name]
            out[f"drag_{name}"] = float(fe[elements, 0::2].sum())
            out[f"lift_{name}"] = float(fe[elements, 1::2].sum())
    return out
