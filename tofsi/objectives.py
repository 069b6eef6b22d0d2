"""Objectives and constraints of a coupled state, with their partial derivatives.

Each quantity ``q(u, x, w, rho)`` gives its value and its partials keyed by
field name, ``{"u": dq/du, "x": dq/dx, "w": dq/dw, "rho": dq/drho}`` (missing
keys are zero), for the adjoint. Shape partials are analytic
(:mod:`tofsi.physics.fluid_shape`), the strain-rate dissipation's by the complex step.
Continuation parameters (the Brinkman q, the load exponent) are the state's
(``state.params``).

* ``compliance``: ``f(w, x, rho) . u`` [J/m] -- the work of the fluid load;
* ``dissipation``: Borrvall & Petersson's (2003) functional
  ``1/2 int (mu grad v : grad v + alpha(rho) |v|^2)`` [W/m] (their total
  potential power without a body force). It is *not* the
  ``dissipated_power`` figure ``int 2 mu eps(v):eps(v) + alpha |v|^2``: for a
  divergence-free velocity that vanishes on the whole boundary
  ``int grad v : grad v = 2 int eps:eps``, so the functional is half the
  dissipated power; with inflow and outflow the two differ by boundary terms;
* ``dissipation-strain``: ``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m]
  (topFlow's objective, the strain-rate form);
* ``pressure-drop``: mean inflow minus mean outflow pressure over the openings [Pa];
* ``volume``: solid fraction of the design region (by reference area), for
  the constraint ``volume / volume_fraction - 1 <= 0``.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.complex_step import corner_derivatives
from tofsi.fem.geometry import physical_gradients
from tofsi.physics.fluid_kernel import N2, POINTS, WEIGHTS
from tofsi.physics.fluid_shape import dissipation_shape
from tofsi.quality import signed_area


class Compliance:
    """The work of the fluid load on the structure's displacement, ``f(w, x, rho) . u`` [J/m]."""

    name, needs = "compliance", "structure"

    def value(self, model, state) -> float:
        return float(model.structure.load(state.w, state.mesh_displacement, state.rho, state.params) @ state.u)

    def partials(self, model, state) -> dict:
        st, X, rho, params, u = model.structure, state.mesh_displacement, state.rho, state.params, state.u
        force = st.force
        out = {"u": st.load(state.w, X, rho, params),
               "w": force.fluid_partial_transpose(u, state.w, X, rho, params),
               "rho": np.einsum("ea,ea->e", u[st.dofs], force.density_vectors(state.w, X, rho, params))}
        if state.x is not None:                       # the flow saw the moved mesh
            out["x"] = force.shape_partial_transpose(u, state.w, X, rho, params)
        return out


class Dissipation:
    """Borrvall & Petersson's functional ``1/2 int (mu grad v : grad v + alpha |v|^2)`` [W/m]."""

    name, needs = "dissipation", "fluid"

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


class StrainDissipation:
    """``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m], ``eps = (grad v + grad v^T)/2``:
    half the power dissipated by the strain-rate (symmetric) viscous form -- topFlow's
    objective ``phi = 1/2 int mu d_j v_i (d_j v_i + d_i v_j) + alpha v_i v_i``
    (Alexandersen 2023). It equals ``dissipation`` plus ``1/2 int mu grad v : grad v^T``,
    a boundary term for divergence-free flow."""

    name, needs = "dissipation-strain", "fluid"

    @staticmethod
    def element_values(flow, Xe, w, rho, params=None) -> np.ndarray:
        ve, _ = flow.split(w)
        grad, det = physical_gradients(Xe, 2, POINTS)
        L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)               # (E, G, 2, 2)
        v = np.matmul(N2, ve)
        strain = np.sum(L * (L + np.swapaxes(L, -1, -2)), axis=(-1, -2))   # 2 eps : eps
        return 0.5 * np.sum(det * WEIGHTS * (flow.settings.viscosity * strain
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
        grad, det = physical_gradients(Xe, 2, POINTS)                       # (E, G, 9, 2)
        wd = det * WEIGHTS
        L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)
        v = np.matmul(N2, ve)
        S = flow.settings.viscosity * (L + np.swapaxes(L, -1, -2))          # (E, G, 2, 2)
        gv = np.einsum("eg,egij,egaj->eai", wd, S, grad)
        gv += flow.alpha(rho, params)[:, None, None] * np.einsum("eg,ga,egi->eai", wd, N2, v)
        ge = np.zeros((Xe.shape[0], 22))
        ge[:, :18] = gv.reshape(-1, 18)
        out = {"w": assemble_vector(flow.dofs, ge, flow.size),
               "rho": 0.5 * flow.brinkman(params).derivative(rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)}
        if state.x is not None:                       # the flow saw the moved mesh
            dphi = corner_derivatives(lambda Xc: self.element_values(flow, Xc, state.w, rho, params), Xe)
            out["x"] = assemble_vector(element_dofs(model.mesh.quads, 2), dphi, 2 * model.mesh.n_nodes)
        return out


class PressureDrop:
    """Mean pressure over the inflow segments minus the mean over the outflow and open
    segments [Pa] (see :mod:`tofsi.physics.flow_boundary`), on any sides. Linear in the
    corner pressures; the channel boundary never moves (the movers fix it), so there is no
    shape partial."""

    name, needs = "pressure-drop", "fluid"

    def value(self, model, state) -> float:
        flow = model.flow
        return float(flow.boundary.pressure_drop_weights() @ state.w[flow.n_velocity:])

    def partials(self, model, state) -> dict:
        flow = model.flow
        g = np.zeros(flow.size)
        g[flow.n_velocity:] = flow.boundary.pressure_drop_weights()
        return {"w": g}


class VolumeFraction:
    """Solid fraction of the design region ``sum_e A_e rho_e / sum_e A_e`` (reference areas)."""

    name = "volume"

    def __init__(self, mesh, design: np.ndarray):
        area = signed_area(mesh.points, mesh.quads)
        self.weights = np.zeros(mesh.n_elements)
        self.weights[design] = area[design] / area[design].sum()

    def value(self, model, state) -> float:
        return float(self.weights @ state.rho)

    def partials(self, model, state) -> dict:
        return {"rho": self.weights.copy()}


OBJECTIVES = {"compliance": Compliance, "dissipation": Dissipation, "pressure-drop": PressureDrop,
              "dissipation-strain": StrainDissipation}
