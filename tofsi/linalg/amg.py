"""Smoothed-aggregation AMG with CG (or GMRES) for the structure and mesh-motion systems."""

from __future__ import annotations

import logging

import numpy as np
import pyamg
import scipy.sparse as sp

from tofsi.core.errors import NumericalError

log = logging.getLogger(__name__)


def rigid_body_modes(points: np.ndarray) -> np.ndarray:
    """The three plane rigid-body modes ``(2 n, 3)`` on node-interleaved dofs."""
    n = points.shape[0]
    B = np.zeros((2 * n, 3))
    B[0::2, 0] = 1.0
    B[1::2, 1] = 1.0
    B[0::2, 2] = -points[:, 1]
    B[1::2, 2] = points[:, 0]
    return B


class AMGSolver:
    """Smoothed-aggregation AMG (pyamg) with CG for symmetric positive definite ``A``.

    near_null : near-null-space vectors (rigid-body modes for elasticity). The
    coarsest level is solved by sparse LU (pyamg's default pseudo-inverse is
    a dense SVD, seconds for a thousand unknowns). A :class:`RecyclingSolver`
    keeps a hierarchy for a sequence of nearby matrices, one V-cycle of it
    preconditioning each (:meth:`preconditioner`), until it goes stale.
    """

    exact = False
    setup_iterations = 12      # a hierarchy costs about 12 preconditioned CG iterations to build

    def __init__(self, A: sp.spmatrix, near_null: np.ndarray | None = None, tol: float = 1e-10,
                 max_iter: int = 500, symmetric: bool = True):
        self.A = sp.csr_matrix(A)
        self.tol, self.max_iter = tol, max_iter
        self.accel = "cg" if symmetric else "gmres"
        self.symmetric = symmetric
        self._ml = pyamg.smoothed_aggregation_solver(
            self.A, B=near_null, symmetry="symmetric" if symmetric else "nonsymmetric",
            max_coarse=300, coarse_solver="splu")
        self.shape = A.shape

    def solve(self, b: np.ndarray) -> np.ndarray:
        residuals: list[float] = []
        x = self._ml.solve(b, tol=self.tol, accel=self.accel, maxiter=self.max_iter, residuals=residuals)
        bnorm = np.linalg.norm(b)
        log.info("AMG-%s: %d iterations, residual %.2e", self.accel.upper(), len(residuals) - 1, residuals[-1])
        if not np.all(np.isfinite(x)) or (bnorm > 0 and residuals[-1] > 10 * self.tol * bnorm):
            raise NumericalError(f"AMG-{self.accel.upper()} did not converge",
                                 {"residual_history": residuals[-20:], "size": self.shape[0]})
        return x

    def preconditioner(self, transpose: bool = False):
        """One V-cycle ``b -> M b`` of this hierarchy, for preconditioning a nearby matrix
        (None for the transpose of a nonsymmetric matrix: the cycle is not transposed)."""
        if transpose and not self.symmetric:
            return None
        cycle = self._ml.aspreconditioner(cycle="V")
        return cycle.matvec

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        if self.accel != "cg":
            return AMGSolver(self.A.T, None, self.tol, self.max_iter, symmetric=False).solve(b)
        return self.solve(b)
