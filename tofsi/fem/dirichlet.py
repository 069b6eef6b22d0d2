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
import scipy.sparse as sp

from tofsi.fem.assembly import SparsePattern


class DirichletOperator:
    """Assemble constrained matrices for element dofs ``rows``/``cols`` ``(E, a)``."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray, size: int, fixed: np.ndarray):
        self.size = size
        self.pattern_rows, self.pattern_cols = rows, cols
        self.fixed = np.unique(np.asarray(fixed, dtype=np.int64))
        self.is_fixed = np.zeros(size, dtype=bool)
        self.is_fixed[self.fixed] = True
        self.free = np.flatnonzero(~self.is_fixed)
        self.keep_rows = ~self.is_fixed[rows][:, :, None]
        self._pattern = None
        self._row_pattern = None

    @property
    def pattern(self) -> SparsePattern:
        """The pattern of :meth:`matrix` (made on first use)."""
        if self._pattern is None:
            self._pattern = self.new_pattern()
        return self._pattern

    def new_pattern(self) -> SparsePattern:
        """A pattern of the constrained matrices (fixed rows and columns dropped, the fixed
        diagonal added), not kept here (for a caller that lays the slots out its own way)."""
        keep = self.keep_rows & ~self.is_fixed[self.pattern_cols][:, None, :]   # (E, a, b): held until the slots
        return SparsePattern(self.pattern_rows, self.pattern_cols, (self.size, self.size),
                             extra_diagonal=self.fixed, keep=keep)

    def matrix(self, Ke: np.ndarray):
        """``K_bc`` from element matrices ``(E, a, b)``."""
        return self.pattern.assemble(Ke, diagonal=1.0)

    def row_matrix(self, Ke: np.ndarray):
        """The true Jacobian of ``[P_f K x; x_p - g]``: fixed rows identity, free rows keep
        their fixed columns ``K_fp`` (needed where ``g`` depends on other fields)."""
        if self._row_pattern is None:
            self._row_pattern = SparsePattern(self.pattern_rows, self.pattern_cols, (self.size, self.size),
                                              extra_diagonal=self.fixed, keep=self.keep_rows)
        return self._row_pattern.assemble(Ke, diagonal=1.0)

    def free_rows(self, M):
        """``M`` with the rows of fixed dofs zeroed (a block coupling into this field)."""
        return sp.diags((~self.is_fixed).astype(float)) @ M

    def homogenize(self, r: np.ndarray) -> np.ndarray:
        """A copy of ``r`` with the fixed entries set to zero."""
        r = np.array(r, copy=True)
        r[self.fixed] = 0.0
        return r
