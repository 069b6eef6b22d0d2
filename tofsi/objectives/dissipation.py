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
from tofsi.fem.geometry import physical_gradients
from tofsi.objectives import Objective
from tofsi.physics.fluid_kernel import N2, POINTS, WEIGHTS
from tofsi.physics.fluid_shape import dissipation_shape
from tofsi.registry import OBJECTIVES


@OBJECTIVES.register
class Dissipation(Objective):
    """Borrvall & Petersson's functional ``1/2 int (mu grad v : grad v + alpha |v|^2)`` [W/m]."""

    name, needs, label, units = "dissipation", "fluid", "dissipation functional", "W/m"

    @staticmethod
    def element_values(flow, Xe, w, rho, params=None) -> np.ndarray:
        ve, _ = flow.split(w)
        grad, det = physical_gradients(Xe, 2, POINTS)
        L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)
        v = np.matmul(N2, ve)
        wd = det * WEIGHTS
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
        grad, det = physical_gradients(Xe, 2, POINTS)
        wd = det * WEIGHTS
        g18 = grad.reshape(grad.shape[0], grad.shape[1], 18)
        M = np.matmul((g18 * wd[..., None]).transpose(0, 2, 1), g18).reshape(-1, 9, 2, 9, 2)
        lap = M[:, :, 0, :, 0] + M[:, :, 1, :, 1]
        mass = np.matmul(N2.T[None] * wd[:, None, :], N2)
        A = flow.settings.viscosity * lap + flow.alpha(rho, params)[:, None, None] * mass   # (E, 9, 9)
        gv = np.matmul(A, ve)                                                       # (E, 9, 2)
        ge = np.zeros((Xe.shape[0], 22))
        ge[:, :18] = gv.reshape(-1, 18)
        v = np.matmul(N2, ve)
        out = {"w": assemble_vector(flow.dofs, ge, flow.size),
               "rho": 0.5 * flow.brinkman(params).derivative(rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)}
        if state.x is not None:                       # the flow saw the moved mesh
            out["x"] = assemble_vector(element_dofs(model.mesh.quads, 2),
                                       dissipation_shape(Xe, ve, flow.alpha(rho, params), flow.settings.viscosity),
                                       2 * model.mesh.n_nodes)
        return out
