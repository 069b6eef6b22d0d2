"""``dissipation``: Borrvall & Petersson's ``1/2 int (mu grad v : grad v + alpha(rho) |v|^2)`` [W/m].

Their total potential power without a body force. It is *not* the
``dissipated_power`` figure ``int 2 mu eps(v):eps(v) + alpha |v|^2``: for a
divergence-free velocity that vanishes on the whole boundary
``int grad v : grad v = 2 int eps:eps``, so the functional is half the
dissipated power; with inflow and outflow the two differ by boundary terms.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.complex_step import corner_derivatives
from tofsi.objectives import Objective
from tofsi.core.registry import OBJECTIVES


@OBJECTIVES.register
class Dissipation(Objective):
    """Borrvall & Petersson's functional ``1/2 int (mu grad v : grad v + alpha |v|^2)`` [W/m]."""

    name, needs, label, units = "dissipation", "fluid", "dissipation functional", "W/m"

    @staticmethod
    def element_values(flow, Xe, w, rho, params=None) -> np.ndarray:
        ve, _ = flow.split(w)
        _, wd, v, L = flow.element.velocity_fields(Xe, ve)
        alpha = flow.alpha(rho, params)
        return 0.5 * np.sum(wd * (flow.settings.viscosity * np.sum(L * L, axis=(-1, -2))
                                  + alpha[:, None] * np.sum(v * v, axis=-1)), axis=1)

    def value(self, model, state) -> float:
        flow = model.flow
        return float(self.element_values(flow, flow.corners(state.mesh_displacement), state.w, state.rho,
                                         state.params).sum())

    def partials(self, model, state) -> dict:
        flow, X, rho, params = model.flow, state.mesh_displacement, state.rho, state.params
        Xe = flow.corners(X)
        ve, _ = flow.split(state.w)
        el = flow.element
        grad, wd, v, _ = el.velocity_fields(Xe, ve)                                # (E, G, k, 2)
        E, G, k = grad.shape[:3]
        gk = grad.reshape(E, G, 2 * k)
        M = np.matmul((gk * wd[..., None]).transpose(0, 2, 1), gk).reshape(E, k, 2, k, 2)
        lap = M[:, :, 0, :, 0] + M[:, :, 1, :, 1]
        mass = np.matmul(el.N.T[None] * wd[:, None, :], el.N)
        A = flow.settings.viscosity * lap + flow.alpha(rho, params)[:, None, None] * mass   # (E, k, k)
        gv = np.matmul(A, ve)                                                       # (E, k, 2)
        ge = np.zeros(flow.dofs.shape)
        ge[:, :2 * k] = gv.reshape(E, 2 * k)
        out = {"w": assemble_vector(flow.dofs, ge, flow.size),
               "rho": 0.5 * flow.brinkman(params).derivative(rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)}
        if state.x is not None:                       # the flow saw the moved mesh
            if el.dissipation_shape is not None:      # Taylor-Hood: analytic
                dphi = el.dissipation_shape(Xe, ve, flow.alpha(rho, params), flow.settings.viscosity)
            else:
                dphi = corner_derivatives(lambda Xc: self.element_values(flow, Xc, state.w, rho, params), Xe)
            out["x"] = assemble_vector(element_dofs(model.mesh.quads, 2), dphi, 2 * model.mesh.n_nodes)
        return out
