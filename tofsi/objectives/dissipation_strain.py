"""``dissipation-strain``: ``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m], topFlow's objective."""

from __future__ import annotations

import numpy as np

from tofsi.objectives import FlowObjective
from tofsi.core.registry import OBJECTIVES


@OBJECTIVES.register
class StrainDissipation(FlowObjective):
    """``1/2 int (2 mu eps(v) : eps(v) + alpha(rho) |v|^2)`` [W/m], ``eps = (grad v + grad v^T)/2``:
    half the power dissipated by the strain-rate (symmetric) viscous form -- topFlow's
    objective ``phi = 1/2 int mu d_j v_i (d_j v_i + d_i v_j) + alpha v_i v_i``
    (Alexandersen 2023). It equals ``dissipation`` plus ``1/2 int mu grad v : grad v^T``,
    a boundary term for divergence-free flow."""

    name, needs, label, units = "dissipation-strain", "w", "strain-rate dissipation functional", "W/m"
    # its shape partial: FlowObjective's complex step through element_values

    def element_values(self, view) -> np.ndarray:
        _, wd, v, L = view.fields                                          # L (E, G, 2, 2)
        c = view.coefficients
        strain = np.sum(L * (L + np.swapaxes(L, -1, -2)), axis=(-1, -2))   # 2 eps : eps
        return 0.5 * np.sum(wd * (c.viscosity * strain + c.alpha[:, None] * np.sum(v * v, axis=-1)), axis=1)

    def element_partials(self, view) -> tuple[np.ndarray, np.ndarray]:
        """``w``: ``int mu (grad v + grad v^T) : grad N_a + alpha v N_a`` per velocity dof;
        ``rho``: ``1/2 alpha'(rho) int |v|^2``."""
        c = view.coefficients
        grad, wd, v, L = view.fields                                        # grad (E, G, k, 2)
        S = c.viscosity * (L + np.swapaxes(L, -1, -2))                      # (E, G, 2, 2)
        gv = np.einsum("eg,egij,egaj->eai", wd, S, grad)
        gv += c.alpha[:, None, None] * np.einsum("eg,ga,egi->eai", wd, view.element.N, v)
        E, k2 = gv.shape[0], gv.shape[1] * 2
        ge = np.zeros(view.dofs.shape)
        ge[:, :k2] = gv.reshape(E, k2)
        return ge, 0.5 * c.brinkman.derivative(view.rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)
