"""Design maps: design variables gamma -> filtered -> projected -> element densities rho.

Each map is a small class with ``forward`` and ``transpose`` (the
vector-Jacobian product), so the chain rule is written once, in
:class:`DesignMap`, where it can be read:

    rho_t = H gamma / Hs                 density filter, H_ij = max(0, r - |c_i - c_j|)
                                         (or TOFLUX's circular sqrt(1 - |c_i - c_j|^2 / r^2))
    rho_p = (tanh(b e) + tanh(b (rho_t - e))) / (tanh(b e) + tanh(b (1 - e)))
    rho   = rho_p in the design region, 1 in fixed solid, 0 in fixed fluid

(Bruns & Tortorelli 2001; Wang, Lazarov & Sigmund 2011). By default the filter averages
over the design elements only; with ``design.filter_fixed`` (TOFLUX's) it also averages the
fixed elements within its radius at their values (1 solid, 0 fluid), ``rho_t = (H gamma + b)
/ Hs`` with the constant ``b``, so the design next to a fixed solid starts partly solid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from tofsi.mesh.structured import DESIGN, SOLID


def filter_weights(distance: np.ndarray, radius: float, kernel: str) -> np.ndarray:
    """Filter weights at ``distance`` <= ``radius``: ``r - d`` (linear hat) or ``sqrt(1 - d^2/r^2)``
    (circular, TOFLUX's)."""
    if kernel == "circular":
        return np.sqrt(np.maximum(0.0, 1.0 - (distance / radius) ** 2))
    return radius - distance


class DensityFilter:
    """Density filter over the design elements' centres, radius ``r`` [m]; ``fixed`` (optional
    ``(centres (m, 2), values (m,))``): fixed elements averaged in at their values."""

    def __init__(self, centres: np.ndarray, radius: float, kernel: str = "linear", fixed=None):
        tree = cKDTree(centres)
        D = tree.sparse_distance_matrix(tree, radius, output_type="coo_matrix")
        n = len(centres)
        H = sp.coo_matrix((filter_weights(D.data, radius, kernel), (D.row, D.col)), shape=(n, n)).tocsr()
        self_weight = filter_weights(np.zeros(1), radius, kernel)[0]
        H = H + sp.diags(np.full(n, self_weight) - H.diagonal())   # the element itself (distance 0)
        self.H = H.tocsr()
        self.Hs = np.asarray(self.H.sum(axis=1)).ravel()
        self.b = np.zeros(n)                                       # the fixed elements' share
        if fixed is not None:
            f_centres, f_values = fixed
            F = tree.sparse_distance_matrix(cKDTree(f_centres), radius, output_type="coo_matrix").tocsr()
            F.data = filter_weights(F.data, radius, kernel)
            self.Hs = self.Hs + np.asarray(F.sum(axis=1)).ravel()
            self.b = F @ np.asarray(f_values, dtype=float)

    def forward(self, gamma: np.ndarray) -> np.ndarray:
        return (self.H @ gamma + self.b) / self.Hs

    def transpose(self, bar: np.ndarray) -> np.ndarray:
        return self.H.T @ (bar / self.Hs)


@dataclass(frozen=True)
class Projection:
    """Smoothed Heaviside projection with sharpness ``beta`` and threshold ``eta`` (beta = 0: identity)."""

    beta: float
    eta: float = 0.5

    def forward(self, x: np.ndarray) -> np.ndarray:
        b, e = self.beta, self.eta
        if b < 1e-8:
            return np.asarray(x, dtype=float).copy()
        return (np.tanh(b * e) + np.tanh(b * (x - e))) / (np.tanh(b * e) + np.tanh(b * (1 - e)))

    def derivative(self, x: np.ndarray) -> np.ndarray:
        b, e = self.beta, self.eta
        if b < 1e-8:
            return np.ones_like(x, dtype=float)
        return b * (1 - np.tanh(b * (x - e)) ** 2) / (np.tanh(b * e) + np.tanh(b * (1 - e)))

    def transpose(self, x: np.ndarray, bar: np.ndarray) -> np.ndarray:
        return self.derivative(x) * bar


class DesignMap:
    """gamma (design elements) -> rho (all elements): filter, projection, fixed regions.

    The projection's sharpness ``beta`` is a continuation parameter: an argument of every
    call (the problem's :class:`~tofsi.core.blocks.Continuation` holds it), never stored here.
    """

    def __init__(self, mesh, filter_radius: float, eta: float = 0.5, kernel: str = "linear",
                 filter_fixed: bool = False):
        self.design = np.flatnonzero(mesh.region == DESIGN)
        self.base = (mesh.region == SOLID).astype(float)
        fixed = None
        if filter_fixed:
            others = np.flatnonzero(mesh.region != DESIGN)
            fixed = (mesh.centroids[others], self.base[others])
        self.filter = DensityFilter(mesh.centroids[self.design], filter_radius, kernel, fixed)
        self.eta = eta

    @property
    def size(self) -> int:
        return self.design.size

    def projection(self, beta: float) -> Projection:
        return Projection(beta, self.eta)

    def forward(self, gamma: np.ndarray, beta: float) -> np.ndarray:
        rho = self.base.copy()
        rho[self.design] = self.projection(beta).forward(self.filter.forward(gamma))
        return rho

    def transpose(self, gamma: np.ndarray, beta: float, rho_bar: np.ndarray) -> np.ndarray:
        """``d rho / d gamma`` transposed applied to ``rho_bar`` (E,) -> (n_design,)."""
        filtered = self.filter.forward(gamma)
        return self.filter.transpose(self.projection(beta).transpose(filtered, rho_bar[self.design]))
