"""Objectives and constraints of a coupled state, with their partial derivatives.

Each quantity ``q(u, x, w, rho)`` gives its value and its partials
``{"u": dq/du, "x": dq/dx, "w": dq/dw, "rho": dq/drho}`` (missing keys are zero)
for the adjoint. Shape partials come from the complex step through the same
kernels as the values.

* ``compliance``: ``f(w, x, rho) . u`` [J/m] -- the work of the fluid load;
* ``dissipation``: ``1/2 int (mu grad v : grad v + alpha(rho) |v|^2)`` [W/m]
  (Borrvall & Petersson 2003's total potential power without the body force);
* ``dissipation-strain``: ``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m]
  (topFlow's objective, the strain-rate form);
* ``pressure-drop``: mean inflow minus mean outflow pressure over the openings [Pa];
* ``volume``: solid fraction of the design region (by reference area), for
  the constraint ``volume / volume_fraction - 1 <= 0``.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.geometry import physical_gradients
from tofsi.physics.fluid_kernel import N2, POINTS, WEIGHTS
from tofsi.quality import signed_area

COMPLEX_STEP = 1e-30


def _corner_partial(fn, Xe: np.ndarray, quads: np.ndarray, n_nodes: int) -> np.ndarray:
    """``d/dx sum_e fn(Xe)_e`` (2n,) for a per-element function of the corners (complex step)."""
    vals = np.empty((Xe.shape[0], 8))
    for j in range(8):
        Xc = Xe.astype(complex)
        Xc[:, j // 2, j % 2] += 1j * COMPLEX_STEP
        vals[:, j] = fn(Xc).imag / COMPLEX_STEP
    return assemble_vector(element_dofs(quads, 2), vals, 2 * n_nodes)


class Compliance:
    name = "compliance"

    def value(self, model, state) -> float:
        return float(model.structure.load(state.w, state.displacement, state.rho) @ state.u)

    def partials(self, model, state) -> dict:
        st, X, rho = model.structure, state.displacement, state.rho
        B = st.load_operators(X)
        ue, we = state.u[st.dofs], state.w[model.flow.dofs]
        out = {"u": st.load(state.w, X, rho, B),
               "w": assemble_vector(model.flow.dofs, np.einsum("eab,ea->eb", B, ue) * st.weight(rho)[:, None],
                                    model.flow.size),
               "rho": np.einsum("ea,eab,eb->e", ue, B, we) * st.weight_derivative(rho)}
        if model.two_way:
            out["x"] = -(st.shape_partial(state.w, X, rho).T @ state.u)
        return out


class Dissipation:
    name = "dissipation"

    @staticmethod
    def element_values(flow, Xe, w, rho) -> np.ndarray:
        ve, _ = flow.split(w)
        grad, det = physical_gradients(Xe, 2, POINTS)
        L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)
        v = np.matmul(N2, ve)
        wd = det * WEIGHTS
        alpha = flow.alpha(rho)
        return 0.5 * np.sum(wd * (flow.settings.viscosity * np.sum(L * L, axis=(-1, -2))
                                  + alpha[:, None] * np.sum(v * v, axis=-1)), axis=1)

    def value(self, model, state) -> float:
        flow = model.flow
        return float(self.element_values(flow, flow.corners(state.displacement), state.w, state.rho).sum())

    def partials(self, model, state) -> dict:
        flow, X, rho = model.flow, state.displacement, state.rho
        Xe = flow.corners(X)
        ve, _ = flow.split(state.w)
        grad, det = physical_gradients(Xe, 2, POINTS)
        wd = det * WEIGHTS
        g18 = grad.reshape(grad.shape[0], grad.shape[1], 18)
        M = np.matmul((g18 * wd[..., None]).transpose(0, 2, 1), g18).reshape(-1, 9, 2, 9, 2)
        lap = M[:, :, 0, :, 0] + M[:, :, 1, :, 1]
        mass = np.matmul(N2.T[None] * wd[:, None, :], N2)
        A = flow.settings.viscosity * lap + flow.alpha(rho)[:, None, None] * mass    # (E, 9, 9)
        gv = np.matmul(A, ve)                                                       # (E, 9, 2)
        ge = np.zeros((Xe.shape[0], 22))
        ge[:, :18] = gv.reshape(-1, 18)
        v = np.matmul(N2, ve)
        out = {"w": assemble_vector(flow.dofs, ge, flow.size),
               "rho": 0.5 * flow.brinkman.derivative(rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)}
        if model.two_way:
            out["x"] = _corner_partial(lambda Xc: self.element_values(flow, Xc, state.w, rho), Xe,
                                       model.mesh.quads, model.mesh.n_nodes)
        return out


class StrainDissipation:
    """``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m], ``eps = (grad v + grad v^T)/2``:
    half the power dissipated by the strain-rate (symmetric) viscous form -- topFlow's
    objective ``phi = 1/2 int mu d_j v_i (d_j v_i + d_i v_j) + alpha v_i v_i``
    (Alexandersen 2023). It equals ``dissipation`` plus ``1/2 int mu grad v : grad v^T``,
    a boundary term for divergence-free flow."""

    name = "dissipation-strain"

    @staticmethod
    def element_values(flow, Xe, w, rho) -> np.ndarray:
        ve, _ = flow.split(w)
        grad, det = physical_gradients(Xe, 2, POINTS)
        L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)               # (E, G, 2, 2)
        v = np.matmul(N2, ve)
        strain = np.sum(L * (L + np.swapaxes(L, -1, -2)), axis=(-1, -2))   # 2 eps : eps
        return 0.5 * np.sum(det * WEIGHTS * (flow.settings.viscosity * strain
                                             + flow.alpha(rho)[:, None] * np.sum(v * v, axis=-1)), axis=1)

    def value(self, model, state) -> float:
        flow = model.flow
        return float(self.element_values(flow, flow.corners(state.displacement), state.w, state.rho).sum())

    def partials(self, model, state) -> dict:
        """``w``: ``int mu (grad v + grad v^T) : grad N_a + alpha v N_a`` per velocity dof."""
        flow, X, rho = model.flow, state.displacement, state.rho
        Xe = flow.corners(X)
        ve, _ = flow.split(state.w)
        grad, det = physical_gradients(Xe, 2, POINTS)                       # (E, G, 9, 2)
        wd = det * WEIGHTS
        L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)
        v = np.matmul(N2, ve)
        S = flow.settings.viscosity * (L + np.swapaxes(L, -1, -2))          # (E, G, 2, 2)
        gv = np.einsum("eg,egij,egaj->eai", wd, S, grad)
        gv += flow.alpha(rho)[:, None, None] * np.einsum("eg,ga,egi->eai", wd, N2, v)
        ge = np.zeros((Xe.shape[0], 22))
        ge[:, :18] = gv.reshape(-1, 18)
        out = {"w": assemble_vector(flow.dofs, ge, flow.size),
               "rho": 0.5 * flow.brinkman.derivative(rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)}
        if model.two_way:
            out["x"] = _corner_partial(lambda Xc: self.element_values(flow, Xc, state.w, rho), Xe,
                                       model.mesh.quads, model.mesh.n_nodes)
        return out


class PressureDrop:
    """Mean pressure over the inflow segments minus the mean over the outflow and open
    segments [Pa] (see :mod:`tofsi.physics.flow_boundary`), on any sides. Linear in the
    corner pressures; the channel boundary never moves, so there is no shape partial."""

    name = "pressure-drop"

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
