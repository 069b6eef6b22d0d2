"""``pressure-drop``: mean inflow minus mean outflow pressure over the openings [Pa]."""

from __future__ import annotations

import numpy as np

from tofsi.objectives import Objective
from tofsi.core.registry import OBJECTIVES


@OBJECTIVES.register
class PressureDrop(Objective):
    """Mean pressure over the inflow segments minus the mean over the outflow and open
    segments [Pa] (see :mod:`tofsi.physics.flow_boundary`), on any sides. Linear in the
    corner pressures; the channel boundary never moves (the movers fix it), so there is no
    shape partial."""

    name, needs, label, units = "pressure-drop", "fluid", "pressure drop", "Pa"

    def value(self, model, state) -> float:
        flow = model.flow
        return float(flow.boundary.pressure_drop_weights() @ state.w[flow.n_velocity:])

    def partials(self, model, state) -> dict:
        flow = model.flow
        g = np.zeros(flow.size)
        g[flow.n_velocity:] = flow.boundary.pressure_drop_weights()
        return {"w": g}
