"""``dissipation``: Borrvall & Petersson's ``1/2 int (mu grad v : grad v + alpha(rho) |v|^2)`` [W/m].

Their total potential power without a body force. It is *not* the
``dissipated_power`` figure ``int 2 mu eps(v):eps(v) + alpha |v|^2``: for a
divergence-free velocity that vanishes on the whole boundary
``int grad v : grad v = 2 int eps:eps``, so the functional is half the
dissipated power; with inflow and outflow the two differ by boundary terms.
"""

from __future__ import annotations

import numpy as np

from tofsi.objectives import FlowObjective
from tofsi.core.registry import OBJECTIVES


@OBJECTIVES.register
class Dissipation(FlowObjective):
    """Borrvall & Petersson's functional ``1/2 int (mu grad v : grad v + alpha |v|^2)`` [W/m]."""

    name, needs, label, units = "dissipation", "w", "dissipation functional", "W/m"

    def element_values(self, view) -> np.ndarray:
        _, wd, v, L = view.fields
        c = view.coefficients
        return 0.5 * np.sum(wd * (c.viscosity * np.sum(L * L, axis=(-1, -2))
                                  + c.alpha[:, None] * np.sum(v * v, axis=-1)), axis=1)

    def element_partials(self, view) -> tuple[np.ndarray, np.ndarray]:
        """``w``: ``int mu grad v : grad N_a + alpha v N_a`` per velocity dof; ``rho``:
        ``1/2 alpha'(rho) int |v|^2``."""
        el, c, ve = view.element, view.coefficients, view.ve
        grad, wd, v, _ = view.fields                                                # (E, G, k, 2)
        E, G, k = grad.shape[:3]
        gk = grad.reshape(E, G, 2 * k)
        M = np.matmul((gk * wd[..., None]).transpose(0, 2, 1), gk).reshape(E, k, 2, k, 2)
        lap = M[:, :, 0, :, 0] + M[:, :, 1, :, 1]
        mass = np.matmul(el.N.T[None] * wd[:, None, :], el.N)
        A = c.viscosity * lap + c.alpha[:, None, None] * mass                       # (E, k, k)
        gv = np.matmul(A, ve)                                                       # (E, k, 2)
        ge = np.zeros(view.dofs.shape)
        ge[:, :2 * k] = gv.reshape(E, 2 * k)
        return ge, 0.5 * c.brinkman.derivative(view.rho) * np.sum(wd * np.sum(v * v, axis=-1), axis=1)

    def shape_elements(self, view) -> np.ndarray:
        """Taylor-Hood: analytic (:func:`~tofsi.physics.fluid_shape.dissipation_shape`); else the
        complex step."""
        el, c = view.element, view.coefficients
        if el.dissipation_shape is None:
            return super().shape_elements(view)
        return el.dissipation_shape(view.Xe, view.ve, c.alpha, c.viscosity)
