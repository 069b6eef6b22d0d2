"""A reusable sparse direct solve of ``A x = b`` and ``A^T x = b`` on any backend.

The backend (``superlu``, ``pardiso``, ``petsc``; ``None``: the configured
default, see :func:`tofsi.linalg.backends.set_default`; a model passes its own,
:class:`tofsi.linalg.LinearAlgebra`) analyses the
pattern of ``A`` once (cached across matrices with the same pattern) and
factorizes its values; :meth:`DirectSolver.solve` and
:meth:`DirectSolver.solve_transpose` (for adjoints) then cost two triangular
solves each, plus a residual check.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import scipy.sparse as sp

from tofsi.core.errors import NumericalError
from tofsi.linalg.backends import analysis_for, canonical_csr, get_backend
from tofsi.linalg.ordering import nested_dissection
from tofsi.linalg.solver_kind import SolverKind

log = logging.getLogger(__name__)
PROGRESS_SIZE = 100_000          # systems at least this large report their factorization
ROUND_OFF = 64 * np.finfo(float).eps   # componentwise backward error that counts as exact


class DirectSolver(SolverKind):
    """Sparse LU of ``A``, reusable for ``A x = b`` and ``A^T x = b``.

    coords : optional integer grid positions ``(m, 2)`` of the unknowns, for
    the nested-dissection ordering; perm : a precomputed ordering. Without
    either, SuperLU uses MMD(A^T + A) and PARDISO METIS. Saddle-point systems
    need their pressures ordered last within each block
    (``nested_dissection(..., last=...)``), so diagonal pivots stay usable.
    Each solve checks its residual and refines iteratively (at most twice)
    when it exceeds ``refine_tol`` relative to ``|b|`` and the componentwise
    backward error ``max_i |r_i| / (|A| |x| + |b|)_i`` is above ``ROUND_OFF``:
    at round-off no refinement can gain a digit (a stiff structure with SIMP's
    1e-4 void leaves |r| ~ 1e-11 |b| at a backward error of 1e-15), so the
    triangular solves it would cost are not spent.
    """

    refine_tol = 1e-12
    exact = True               # a RecyclingSolver preconditions GMRES with these factors

    def __init__(self, A: sp.spmatrix, coords: np.ndarray | None = None, perm: np.ndarray | None = None,
                 backend: str | None = None, threads: int | None = None):
        A = canonical_csr(A)
        if perm is None and coords is not None:
            perm = nested_dissection(coords)
        self.A, self.perm = A, perm
        self.backend = get_backend(backend if A.dtype == np.float64 else "superlu")
        self.threads = threads
        if threads:                                      # the model's own thread count
            self.backend.set_threads(threads)
        t0 = time.perf_counter()
        if A.shape[0] >= PROGRESS_SIZE:
            log.info("factorizing %d unknowns (%d non-zeros) with %s ...", A.shape[0], A.nnz, self.backend.name)
        self.factorization = analysis_for(A, self.backend, perm).factorize(A)
        if A.shape[0] >= PROGRESS_SIZE:
            log.info("... factorized in %.1f s, %.2f GB of factors", time.perf_counter() - t0,
                     self.factorization.memory_bytes / 1024**3)
        self.memory_bytes = self.factorization.memory_bytes
        self.shape = A.shape
        self.dtype = A.dtype
        self._abs = None                                 # |A| (made on the first refinement test)

    def backward_error(self, b: np.ndarray, x: np.ndarray, r: np.ndarray, trans: str) -> float:
        """Componentwise backward error ``max_i |r_i| / (|A| |x| + |b|)_i`` of ``x`` (rows with a
        zero denominator, where ``r_i`` is zero too, left out)."""
        if self._abs is None:
            self._abs = abs(self.A)
        size = (self._abs if trans == "N" else self._abs.T) @ np.abs(x) + np.abs(b)
        rows = size > 0
        return float(np.max(np.abs(r[rows]) / size[rows], initial=0.0))

    def _apply(self, b: np.ndarray, trans: str, rtol: float | None = None) -> np.ndarray:
        A = self.A if trans == "N" else self.A.T
        if self.threads:
            self.backend.set_threads(self.threads)
        x = self.factorization.solve(b, trans)
        goal = max(self.refine_tol, rtol or 0.0) * np.linalg.norm(b)
        for _ in range(2):                               # iterative refinement
            r = b - A @ x
            if (not np.all(np.isfinite(x)) or np.linalg.norm(r) <= goal
                    or self.backward_error(b, x, r, trans) <= ROUND_OFF):
                break
            x = x + self.factorization.solve(r, trans)
        if not np.all(np.isfinite(x)):
            raise NumericalError("linear solve produced non-finite values (singular matrix?)",
                                 {"size": self.shape[0], "backend": self.backend.name})
        return x

    def solve(self, b: np.ndarray, rtol: float | None = None) -> np.ndarray:
        """``A^-1 b``, refined until the residual is below ``max(refine_tol, rtol) |b|``."""
        return self._apply(b, "N", rtol)

    def preconditioner(self, transpose: bool = False):
        """``b -> A^-1 b`` (or ``A^-T b``) by the triangular solves alone: a fixed linear
        operator for preconditioning another matrix (no residual check, no refinement)."""
        trans = "T" if transpose else "N"
        return lambda b: self.factorization.solve(b, trans)

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        return self._apply(b, "T")
