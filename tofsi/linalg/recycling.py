"""A sequence of slowly changing systems solved with an old factorization as preconditioner."""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse.linalg as spla

log = logging.getLogger(__name__)


class RecyclingSolver:
    """Solve a sequence of slowly changing systems ``A_k x = b`` cheaply.

    The last factorization (or AMG hierarchy) preconditions GMRES on the new
    matrix; when GMRES needs more than ``max_iter`` iterations the new matrix
    is factorized instead, and when a solve needed more than ``refresh_after``
    iterations the next matrix is (the preconditioner has gone stale). The
    rule counts iterations, not seconds, so results never depend on timing
    (bitwise reproducible runs). Newton tangents of
    consecutive iterations and increments differ little, so most solves cost a
    few triangular solves instead of a factorization. Solves are converged to
    ``rtol`` (relative to ``|b|``), so the answers are those of the new matrix,
    not the old.
    """

    def __init__(self, factorize, max_iter: int = 20, rtol: float = 1e-10, refresh_after: int = 6):
        self.factorize, self.max_iter, self.rtol = factorize, max_iter, rtol
        self.refresh_after = refresh_after
        self.solver = None
        self.stale = False
        self.factorizations = 0
        self.krylov_iterations = 0

    def refresh(self, A) -> None:
        self.solver = None                 # release the old factors (and their backend slot) first
        log.info("new factorization of %d unknowns", A.shape[0])
        self.solver = self.factorize(A)
        self.stale = False
        self.factorizations += 1

    def _krylov(self, A, b, apply, x0=None, rtol=None):
        """Right-preconditioned GMRES: minimizes the true residual ``|b - A x|``."""
        n = A.shape[0]
        rtol = self.rtol if rtol is None else max(rtol, self.rtol)
        dtype = np.result_type(A.dtype, b.dtype)
        r0 = b if x0 is None else b - A @ x0
        goal = rtol * np.linalg.norm(b)
        if np.linalg.norm(r0) <= goal:
            return (np.zeros_like(b) if x0 is None else x0), True
        AM = spla.LinearOperator((n, n), matvec=lambda v: A @ apply(v), dtype=dtype)
        count = [0]

        def tick(_):
            count[0] += 1
        y, info = spla.gmres(AM, r0, rtol=0.0, atol=goal, restart=self.max_iter, maxiter=1,
                             callback=tick, callback_type="pr_norm")
        self.krylov_iterations += count[0]
        self.stale = count[0] > self.refresh_after
        x = apply(y) if x0 is None else x0 + apply(y)
        residual = np.linalg.norm(b - A @ x)
        log.info("GMRES: %d iterations, residual %.2e relative to |b|", count[0], residual / np.linalg.norm(b))
        ok = info == 0 and np.all(np.isfinite(x)) and residual <= 1.01 * goal
        return x, ok

    def solve(self, A, b: np.ndarray, guess: np.ndarray | None = None,
              rtol: float | None = None) -> np.ndarray:
        """Solve ``A x = b``; ``guess`` (e.g. the previous increment) starts GMRES,
        ``rtol`` loosens the tolerance for this solve (inexact Newton)."""
        if not np.any(b):
            return np.zeros_like(b)
        if self.solver is not None and not self.stale and getattr(self.solver, "recycle", True):
            x, ok = self._krylov(A, b, self.solver.solve, guess, rtol)
            if ok:
                return x
        self.refresh(A)
        return self.solver.solve(b)

    def solve_transpose(self, A, b: np.ndarray) -> np.ndarray:
        if not np.any(b):
            return np.zeros_like(b)
        if self.solver is not None and not self.stale and getattr(self.solver, "recycle", True):
            x, ok = self._krylov(A.T, b, self.solver.solve_transpose)
            if ok:
                return x
        self.refresh(A)
        return self.solver.solve_transpose(b)
