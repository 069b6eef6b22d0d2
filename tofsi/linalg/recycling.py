"""A sequence of slowly changing systems solved with an old factorization or hierarchy as preconditioner."""

from __future__ import annotations

import logging
import math

import numpy as np
import pyamg.krylov
import scipy.sparse.linalg as spla

from tofsi.core.errors import NumericalError
from tofsi.linalg.krylov import gmres

log = logging.getLogger(__name__)


def flexible_gmres(A, b: np.ndarray, apply, goal: float, max_iter: int, restart: int, x0=None):
    """Right-preconditioned (flexible) GMRES on ``A x = b`` with the preconditioner ``apply``,
    to the absolute residual ``goal``: it minimizes the true residual ``|b - A x|`` and keeps
    the preconditioned basis, so the update needs no extra preconditioner application;
    ``(x, iterations)``."""
    n = A.shape[0]
    M = spla.LinearOperator((n, n), matvec=apply, dtype=np.result_type(A.dtype, b.dtype))
    residuals: list[float] = []
    bnorm = float(np.linalg.norm(b))
    x, _ = pyamg.krylov.fgmres(A, b, x0=x0, tol=goal / bnorm, restart=min(restart, max_iter),
                               maxiter=max(1, -(-max_iter // restart)), M=M, residuals=residuals)
    return x, len(residuals) - 1


class RecyclingSolver:
    """Solve a sequence of slowly changing systems ``A_k x = b`` cheaply.

    ``factorize(A)`` makes a solver of one of two kinds:

    * exact (sparse LU, ``exact = True``): the last factors precondition GMRES
      on the new matrix; when GMRES needs more than ``max_iter`` iterations the
      new matrix is factorized instead, and when a solve needed more than
      ``refresh_after`` iterations the next matrix is (the factors have gone
      stale). Newton tangents of consecutive iterations and increments differ
      little, so most solves cost a few triangular solves instead of a
      factorization.
    * iterative (an AMG hierarchy, or a :class:`~tofsi.linalg.BlockGaussSeidel`
      sweep over a coupled matrix's own blocks; ``exact = False``): every solve
      is a Krylov solve (CG for symmetric systems, else GMRES) preconditioned
      by one cycle (or sweep) of the last one. The first solve after a new
      one measures its cost ``c``, iterations per decade of residual
      reduction. A new one
      costs about ``s = solver.setup_iterations`` iterations to build, so a
      later solve over ``d`` decades that needed more than ``c d + s``
      iterations marks the hierarchy stale (the next matrix gets a new one),
      and one that would need more than ``c d + 2 s`` is stopped and finished
      by a new hierarchy from where it stopped.

    The rules count iterations, not seconds, so results never depend on
    timing (bitwise reproducible runs). Solves are converged to ``rtol``
    (relative to ``|b|``; a caller may loosen it per solve for inexact Newton),
    so the answers are those of the new matrix, not the old.
    """

    def __init__(self, factorize, max_iter: int = 20, rtol: float = 1e-10, refresh_after: int = 6):
        self.factorize, self.max_iter, self.rtol = factorize, max_iter, rtol
        self.refresh_after = refresh_after
        self.solver = None
        self.stale = False
        self.fresh_cost = None             # iterations per decade of a fresh hierarchy
        self.last_cost = None              # iterations per decade of the latest solve
        self.last_excess = None            # its iterations beyond a fresh one's over its decades
        self.factorizations = 0
        self.krylov_iterations = 0

    def with_factorize(self, factorize) -> "RecyclingSolver":
        """A solver for a new sequence of systems (the next design's) that starts from this
        one's factorization or hierarchy and builds new ones with ``factorize`` (this one is
        left as it is)."""
        other = RecyclingSolver(factorize, self.max_iter, self.rtol, self.refresh_after)
        other.solver, other.stale, other.fresh_cost = self.solver, self.stale, self.fresh_cost
        return other

    def refresh(self, A) -> None:
        self.solver = None                 # release the old factors (and their backend slot) first
        log.info("new factorization (or hierarchy) of %d unknowns", A.shape[0])
        self.solver = self.factorize(A)
        self.stale = False
        self.fresh_cost = self.last_cost = self.last_excess = None
        self.factorizations += 1

    def _usable(self, A) -> bool:
        return self.solver is not None and not self.stale and self.solver.shape == A.shape

    def _cg(self, A, b, apply, x0, goal: float, max_iter: int):
        """Preconditioned CG (symmetric positive definite ``A`` and preconditioner); (x, iterations)."""
        n = A.shape[0]
        M = spla.LinearOperator((n, n), matvec=apply, dtype=b.dtype)
        residuals: list[float] = []
        bnorm = float(np.linalg.norm(b))
        x, _ = pyamg.krylov.cg(A, b, x0=x0, tol=goal / bnorm, maxiter=max_iter, M=M, residuals=residuals)
        return x, len(residuals) - 1

    def _krylov(self, A, b, x0=None, rtol=None, transpose=False, setups: int = 2):
        """Solve with the current solver as preconditioner: (x, converged). An iterative solver
        stops after its fresh cost over the decades and ``setups`` times its setup."""
        rtol = self.rtol if rtol is None else max(rtol, self.rtol)
        bnorm = float(np.linalg.norm(b))
        goal = rtol * bnorm
        r0 = bnorm if x0 is None else float(np.linalg.norm(b - A @ x0))
        if r0 <= goal:
            return (np.zeros_like(b) if x0 is None else x0), True
        apply = (self.solver.preconditioner(transpose, matrix=A) if self.solver.follows_matrix
                 else self.solver.preconditioner(transpose))
        try:
            if self.solver.exact:
                x, its = flexible_gmres(A, b, apply, goal, self.max_iter, self.max_iter, x0)
                self.stale = its > self.refresh_after
            else:
                setup = self.solver.setup_iterations
                cap = (self.solver.max_iter if self.fresh_cost is None
                       else int(self.fresh_cost * math.log10(r0 / goal) + setups * setup) + 1)
                if self.solver.symmetric:
                    x, its = self._cg(A, b, apply, x0, goal, cap)
                else:                      # GMRES(m) for a fixed linear preconditioner, else FGMRES
                    x, its = gmres(A, b, apply, goal, cap, self.solver.restart, x0,
                                   flexible=not self.solver.linear_preconditioner)
        except ValueError:                      # an overflow in the Krylov basis (SciPy refuses inf): not
            log.info("Krylov solve: the basis overflowed")            # converged, as a NaN iterate is
            return np.full_like(b, np.nan), False
        self.krylov_iterations += its
        residual = float(np.linalg.norm(b - A @ x))
        ok = bool(np.all(np.isfinite(x))) and residual <= 1.01 * goal
        if not self.solver.exact and ok:
            decades = max(math.log10(r0 / max(residual, 1e-300)), 0.1)
            if self.fresh_cost is None:
                self.fresh_cost = its / decades
            self.last_cost = its / decades
            self.last_excess = its - self.fresh_cost * decades
            self.stale = self.last_excess > self.solver.setup_iterations
        log.info("%s: %d iterations, residual %.2e relative to |b|",
                 "GMRES" if self.solver.exact or not self.solver.symmetric else "CG", its, residual / bnorm)
        return x, ok

    def solve(self, A, b: np.ndarray, guess: np.ndarray | None = None,
              rtol: float | None = None) -> np.ndarray:
        """Solve ``A x = b``; ``guess`` (e.g. the previous increment) starts the iteration,
        ``rtol`` loosens the tolerance for this solve (inexact Newton)."""
        if not np.any(b):
            return np.zeros_like(b)
        if self._usable(A):
            x, ok = self._krylov(A, b, guess, rtol)
            if ok:
                return x
            guess = x if np.all(np.isfinite(x)) else guess
        self.refresh(A)
        if self.solver.exact:
            return self.solver.solve(b) if rtol is None else self.solver.solve(b, max(rtol, self.rtol))
        x, ok = self._krylov(A, b, guess, rtol)
        if not ok:
            raise NumericalError("preconditioned Krylov solve did not converge",
                                 {"size": A.shape[0], "rtol": rtol or self.rtol})
        return x

    def _dearer_than_fresh(self, decades: float) -> bool:
        """An iterative solver whose latest solve's cost per decade, over ``decades``, would
        exceed a fresh one's and its setup (a Newton that moved far since it was built leaves
        it so for the adjoint's long solve)."""
        if self.solver is None or self.solver.exact or self.fresh_cost is None or self.last_cost is None:
            return False
        return (self.last_cost - self.fresh_cost) * decades > self.solver.setup_iterations

    def _refresh_partly(self, A) -> bool:
        """Refactorize at ``A`` the cheap part of a preconditioner that has one (a block
        preconditioner's small diagonal blocks, :meth:`BlockGaussSeidel.refactor_small_blocks`);
        True when done. A failed factorization leaves the solver stale."""
        if not self._usable(A):
            return False
        try:
            refactorized = self.solver.refactor_small_blocks(A)
        except ValueError:                  # not a block matrix of the preconditioner's sizes
            return False
        except NumericalError:
            self.stale = True
            return False
        if refactorized is None:            # no cheap part
            return False
        self.last_cost = self.last_excess = None
        return True

    def solve_transpose(self, A, b: np.ndarray) -> np.ndarray:
        """Solve ``A^T x = b`` (adjoints), to the solver's own tolerance. An iterative solver
        grown dearer than a fresh one over this solve's decades has its cheap part refactorized
        at ``A`` first where it has one (the small fields' blocks: what a Newton that moved far
        changed most), and the solve may then take what a fresh one would (its fresh cost and
        one setup) before a new one is built at ``A``; without a cheap part it is rebuilt first."""
        if not np.any(b):
            return np.zeros_like(b)
        setups = 2
        if self._dearer_than_fresh(-math.log10(self.rtol)):
            log.info("the preconditioner went stale over the Newton steps (%.1f iterations per decade, "
                     "%.1f fresh); its cheap part refactorized, else a new one, for the transposed solve",
                     self.last_cost, self.fresh_cost)
            partly = self._refresh_partly(A)
            self.stale, setups = not partly, 1
        if self._usable(A) and self.solver.own_krylov:
            try:
                return self.solver.solve_with(A, b, transpose=True)
            except NumericalError:
                pass                                                  # stale: a new one below
        elif self._usable(A) and self.solver.preconditioner(True) is not None:
            x, ok = self._krylov(A.T, b, transpose=True, setups=setups)
            if ok:
                return x
        self.refresh(A)
        return self.solver.solve_transpose(b)
