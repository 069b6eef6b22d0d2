"""``dissipation-strain``: ``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m], topFlow's objective."""

from __future__ import annotations

import numpy as np

from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.complex_step import corner_derivatives
from tofsi.objectives import Objective
from tofsi.core.registry import OBJECTIVES


@OBJECTIVES.register
class StrainDissipation(Objective):
    """``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m], ``eps = (grad v + grad v^T)/2``:
    half the power dissipated by the strain-rate (symmetric) viscous form -- topFlow's
    objective ``phi = 1/2 int mu d_j v_i (d_j v_i + d_i v_j) + alpha v_i v_i``
    (Alexandersen 2023). It equals ``dissipation`` plus ``1/2 int mu grad v : grad v^T``,
    a boundary term for divergence-free flow."""

    name, needs, label, units = "dissipation-strain", "fluid", "strain-rate dissipation functional", "W/m"

    @staticmethod
    def element_values(flow, Xe, w, rho, params=None) -> np.ndarray:
        ve, _ = flow.split(w)
        _, wd, v, L = flow.element.velocity_fields(Xe, ve)                 # L (E, G, 2, 2)
        strain = np.sum(L * (L + np.swapaxes(L, -1, -2)), axis=(-1, -2))   # 2 eps : eps
        return 0.5 * np.sum(wd * (flow.settings.viscosity * strain
                                  + flow.alpha(rho, params)[:, None] * np.sum(v * v, axis=-1)), axis=1)

    def value(self, model, state) -> float:
        flow = model.flow
        return float(self.element_values(flow, flow.corners(state.mesh_displacement), state.w, state.rho,
                                         state.params).sum())

    def partials(self, model, state) -> dict:
        """``w``: ``int mu (grad v + grad v^T) : grad N_a + alpha v N_a`` per velocity dof; ``x`` by
        the complex step through :meth:`element_values`."""
        flow, X, rho, params = model.flow, state.mesh_displacement, state.rho, state.params
        Xe = flow.corners(X)
        ve, _ = flow.split(state.w)
        grad, wd, v, L = flow.element.velocity_fields(Xe, ve)               # grad (E, G, k, 2)
        S = flow.settings.viscosity * (L + np.swapaxes(L, -1, -2))          # (E, G, 2, 2)
        gv = np.einsum("eg,egij,egaj->eai", wd, S, grad)
        gv += flow.alpha(rho, params)[:, None, None] * np.einsum("eg,ga,egi->eai", wd, flow.element.N, v)
        E, k2 = gv.shape[0], gv.shape[1] * 2
        ge = np.zeros(flow.dofs.shape)
        ge[:, :k2] = gv.reshape(E, k2)
        out = {"w": assemble_vector(flow.dofs, ge, flow.size),
               "rho": 0.5 * flow.brinkman(params).derivative(rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)}
        if state.x is not None:                       # the flow saw the moved mesh
            dphi = corner_derivatives(lambda Xc: self.element_values(flow, Xc, state.w, rho, params), Xe)
            out["x"] = assemble_vector(element_dofs(model.mesh.quads, 2), dphi, 2 * model.mesh.n_nodes)
        return out
