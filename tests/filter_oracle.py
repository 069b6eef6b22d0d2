"""The density filter as tofsi built it up to issue 34: the matrix ``H`` from a k-d tree of the
element centres (every pair within the radius), the oracle of the stencil filter."""

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from tofsi.mesh.structured import DESIGN, SOLID


def weights(distance, radius, kernel):
    if kernel == "circular":
        return np.sqrt(np.maximum(0.0, 1.0 - (distance / radius) ** 2))
    return radius - distance


class MatrixFilter:
    """``rho_t = (H gamma + b) / Hs`` over the design elements of ``mesh``, ``H`` stored."""

    def __init__(self, mesh, radius, kernel="linear", filter_fixed=False):
        design = np.flatnonzero(mesh.region == DESIGN)
        centres = mesh.centroids[design]
        tree = cKDTree(centres)
        D = tree.sparse_distance_matrix(tree, radius, output_type="coo_matrix")
        n = len(centres)
        H = sp.coo_matrix((weights(D.data, radius, kernel), (D.row, D.col)), shape=(n, n)).tocsr()
        H = H + sp.diags(np.full(n, weights(np.zeros(1), radius, kernel)[0]) - H.diagonal())
        self.H = H.tocsr()
        self.Hs = np.asarray(self.H.sum(axis=1)).ravel()
        self.b = np.zeros(n)
        if filter_fixed:
            others = np.flatnonzero(mesh.region != DESIGN)
            F = tree.sparse_distance_matrix(cKDTree(mesh.centroids[others]), radius,
                                            output_type="coo_matrix").tocsr()
            F.data = weights(F.data, radius, kernel)
            self.Hs = self.Hs + np.asarray(F.sum(axis=1)).ravel()
            self.b = F @ (mesh.region[others] == SOLID).astype(float)

    def forward(self, gamma):
        return (self.H @ gamma + self.b) / self.Hs

    def transpose(self, bar):
        return self.H.T @ (bar / self.Hs)
