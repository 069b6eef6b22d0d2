"""Design maps: design variables gamma -> filtered -> projected -> element densities rho.

Each map is a small class with ``forward`` and ``transpose`` (the
vector-Jacobian product), so the chain rule is written once, in
:class:`DesignMap`, where it can be read:

    rho_t = H gamma / Hs                 density filter, H_ij = max(0, r - |c_i - c_j|)
    rho_p = (tanh(b e) + tanh(b (rho_t - e))) / (tanh(b e) + tanh(b (1 - e)))
    rho   = rho_p in the design region, 1 in fixed solid, 0 in fixed fluid

(Bruns & Tortorelli 2001; Wang, Lazarov & Sigmund 2011).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from tofsi.mesh import DESIGN, SOLID


class DensityFilter:
    """Linear density filter over the design elements' centres, radius ``r`` [m]."""

    def __init__(self, centres: np.ndarray, radius: float):
        tree = cKDTree(centres)
        D = tree.sparse_distance_matrix(tree, radius, output_type="coo_matrix")
        weights = radius - D.data
        n = len(centres)
        H = sp.coo_matrix((weights, (D.row, D.col)), shape=(n, n)).tocsr()
        H = H + sp.diags(np.full(n, radius) - H.diagonal())   # the element itself (distance 0)
        self.H = H.tocsr()
        self.Hs = np.asarray(self.H.sum(axis=1)).ravel()

    def forward(self, gamma: np.ndarray) -> np.ndarray:
        return self.H @ gamma / self.Hs

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
    call (the problem's :class:`~tofsi.blocks.Continuation` holds it), never stored here.
    """

    def __init__(self, mesh, filter_radius: float, eta: float = 0.5):
        self.design = np.flatnonzero(mesh.region == DESIGN)
        self.base = (mesh.region == SOLID).astype(float)
        self.filter = DensityFilter(mesh.centroids[self.design], filter_radius)
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
