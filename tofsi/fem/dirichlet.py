"""Dirichlet conditions by identity rows, on a fixed sparse pattern.

The constrained system keeps the pattern of ``K``: every entry in a fixed
row or column is zeroed and the fixed diagonal set to 1, so

    K_bc = P K P + (I - P),    P = diag(1 on free dofs, 0 on fixed dofs).

Newton-type solves then read ``K_bc dx = -r`` with ``r`` zero on the fixed
dofs (their values are already in place), and an adjoint solve reads
``K_bc^T lam = -g`` with ``g`` zeroed on the fixed dofs: forward and adjoint
use the same operator, homogeneous for the adjoint.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.assembly import SparsePattern


class DirichletOperator:
    """Assemble constrained matrices for element dofs ``rows``/``cols`` ``(E, a)``."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray, size: int, fixed: np.ndarray):
        self.size = size
        self.fixed = np.unique(np.asarray(fixed, dtype=np.int64))
        self.is_fixed = np.zeros(size, dtype=bool)
        self.is_fixed[self.fixed] = True
        self.free = np.flatnonzero(~self.is_fixed)
        self.keep = ~(self.is_fixed[rows][:, :, None] | self.is_fixed[cols][:, None, :])
        self.pattern = SparsePattern(rows, cols, (size, size), extra_diagonal=self.fixed)

    def matrix(self, Ke: np.ndarray):
        """``K_bc`` from element matrices ``(E, a, b)``."""
        return self.pattern.assemble(np.where(self.keep, Ke, 0.0), diagonal=1.0)

    def homogenize(self, r: np.ndarray) -> np.ndarray:
        """A copy of ``r`` with the fixed entries set to zero."""
        r = np.array(r, copy=True)
        r[self.fixed] = 0.0
        return r
