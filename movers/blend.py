"""Density-blended mesh motion: the mover in the fluid, the structure in the solid.

For a node ``i`` with solid indicator ``s_i`` in [0, 1] (and not on the
channel boundary) the mesh-motion equation becomes

    D_i(x) = (1 - s_i) R_i(x) + s_i c_i (x_i - u_i) = 0,

``R`` the mover's residual (or its increment equations), ``u`` the structural
displacement and ``c_i`` a stiffness scale (the mean diagonal of the mover's
reference stiffness at the node) that keeps both parts of comparable size.
``s = 0`` everywhere is the explicit-interface form; ``s = 1`` on the solid's
nodes makes them follow the structure exactly: their row is ``c_i (x_i - u_i)``,
linear, so ``x_i = u_i`` to round-off whatever the mover's forces. ``s`` must be
exactly 1 for that, not near it: with ``s = 1 - d`` the node settles where
``d R_i ~ c_i (x_i - u_i)``, and a stiffened nonlinear mover's ``|R_i| / c_i`` is
of the order of 100 m at a large motion (the coupled model's indicator is 1 from
a density threshold on: :mod:`tofsi.physics.indicators`). Per dof this is a row weight
``W = 1 - s`` on the mover's equations plus a diagonal ``S_c = s c``. This
module is the only place that writes that algebra down: the blended residual,
its Jacobian and its partial derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tofsi.fem.assembly import assemble_vector


@dataclass(frozen=True, eq=False)
class Blend:
    """Per-dof row weights ``W = 1 - s`` and diagonal ``S_c = s c`` (zero on fixed dofs)."""

    s: np.ndarray          # (n,) solid indicator per node
    c: np.ndarray          # (n,) stiffness scale per node
    weight: np.ndarray     # (2n,)
    diag: np.ndarray       # (2n,)

    @classmethod
    def build(cls, s: np.ndarray, c: np.ndarray, is_fixed: np.ndarray) -> "Blend":
        s_dof, c_dof = np.repeat(s, 2), np.repeat(c, 2)
        weight = np.where(is_fixed, 1.0, 1.0 - s_dof)
        diag = np.where(is_fixed, 0.0, s_dof * c_dof)
        return cls(s, c, weight, diag)

    def weighted(self, v: np.ndarray) -> np.ndarray:
        return self.weight * v

    def residual(self, r: np.ndarray, x: np.ndarray, target: np.ndarray) -> np.ndarray:
        """``W r + S_c (x - target)`` (2n,) from the mover's assembled residual ``r``."""
        return self.weight * r + self.diag * (x - target)

    def matrix(self, bc, Ke: np.ndarray, dofs: np.ndarray) -> sp.csr_matrix:
        """``P_f (W K + S_c) P_f + P_p`` from element matrices of ``K`` (constant fixed values)."""
        return bc.matrix(Ke * self.weight[dofs][:, :, None]) + sp.diags(self.diag)

    def row_matrix(self, bc, Ke: np.ndarray, dofs: np.ndarray) -> sp.csr_matrix:
        """``P_f (W K + S_c) + P_p``: the free rows keep their fixed columns (true Jacobian)."""
        return (bc.row_matrix(Ke * self.weight[dofs][:, :, None]) + sp.diags(self.diag)).tocsr()

    def partials(self, lam: np.ndarray, x: np.ndarray, target: np.ndarray, r: np.ndarray):
        """``lam^T d(W r + S_c (x - target))/d(target, s)`` for free-row multipliers ``lam``:
        ``-S_c lam`` (2n,) and ``lam_i . (c_i (x_i - target_i) - r_i)`` (n,)."""
        s_bar = (lam * (np.repeat(self.c, 2) * (x - target) - r)).reshape(-1, 2).sum(axis=1)
        return -self.diag * lam, s_bar


def node_scale(Ke: np.ndarray, dofs: np.ndarray, n_nodes: int) -> np.ndarray:
    """Mean diagonal of the assembled matrix at each node ``(n,)``."""
    diag = assemble_vector(dofs, np.diagonal(Ke, axis1=1, axis2=2), 2 * n_nodes)
    c = diag.reshape(-1, 2).mean(axis=1)
    return np.where(c > 0, c, c[c > 0].mean() if np.any(c > 0) else 1.0)
