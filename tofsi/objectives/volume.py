"""The volume constraint's quantity: the solid fraction of the design region (not an objective)."""

from __future__ import annotations

import numpy as np

from tofsi.mesh.quality import signed_area


class VolumeFraction:
    """Solid fraction of the design region ``sum_e A_e rho_e / sum_e A_e`` (reference areas), for
    the constraint ``volume / volume_fraction - 1 <= 0``."""

    name = "volume"

    def __init__(self, mesh, design: np.ndarray):
        area = signed_area(mesh.points, mesh.quads)
        self.weights = np.zeros(mesh.n_elements)
        self.weights[design] = area[design] / area[design].sum()

    def value(self, model, state) -> float:
        return float(self.weights @ state.rho)

    def partials(self, model, state) -> dict:
        return {"rho": self.weights.copy()}
