"""Linear solvers: sparse LU with a grid nested-dissection ordering, and AMG.

On a structured grid every unknown has integer grid coordinates (Q1 node
``(i, j)`` sits at fine-grid position ``(2i, 2j)``, Q2 nodes on the fine grid
itself). Recursively cutting the grid along its longer side and numbering
the cut last (nested dissection) gives SuperLU far less fill than its
built-in column orderings: on plane-strain elasticity with 1.6e5 unknowns
the factorization is about 3x faster than ``MMD_AT_PLUS_A`` (see
``benchmarks/README.md``).

A factorization is kept and reused: :meth:`DirectSolver.solve` and
:meth:`DirectSolver.solve_transpose` (for adjoints) cost two triangular
solves each.
"""

from __future__ import annotations

import logging

import numpy as np
import pyamg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tofsi.errors import NumericalError

log = logging.getLogger(__name__)


def nested_dissection(coords: np.ndarray, leaf: int = 32, last=None) -> np.ndarray:
    """Permutation of unknowns with integer fine-grid positions ``coords`` ``(m, 2)``.

    Element corners sit on even fine-grid lines (Q2 mid-nodes on odd ones),
    so every cut is an even line: it separates the elements on its two sides.
    Each block of grid positions is cut at the middle of its longer side; the
    two halves are numbered first, the cut (separator) last. Unknowns at the
    same position (the components of a node, a velocity and a pressure) stay
    together; blocks of at most ``leaf`` positions are numbered as they come.

    last : optional boolean per unknown; within every block these come after
    the others. For saddle-point systems (pressures last) every pressure is
    eliminated after the velocities it couples to in its block, so its pivot is
    a non-zero Schur complement and the LU can keep the diagonal pivots.
    """
    coords = np.asarray(coords, dtype=np.int64)
    key = coords[:, 0] * (coords[:, 1].max() + 1) + coords[:, 1]
    unique_key, where = np.unique(key, return_inverse=True)
    P = coords[_first_index(where, unique_key.size)]              # one row per position
    order: list[np.ndarray] = []
    stack: list[tuple[bool, np.ndarray]] = [(False, np.arange(P.shape[0]))]
    while stack:                                   # post-order with an explicit stack
        emit, idx = stack.pop()
        if emit or idx.size <= leaf:
            order.append(idx)
            continue
        c = P[idx]
        lo, hi = c.min(axis=0), c.max(axis=0)
        axis = int(np.argmax(hi - lo))
        lo, hi = lo[axis], hi[axis]
        mid = 2 * ((lo + hi) // 4)                 # an even line near the middle
        on_line = c[:, axis] == mid
        if not (lo < mid < hi) or not on_line.any():
            lines = np.unique(c[:, axis])
            lines = lines[(lines % 2 == 0) & (lines > lo) & (lines < hi)]
            if lines.size == 0:
                order.append(idx)
                continue
            mid = lines[lines.size // 2]
            on_line = c[:, axis] == mid
        stack.append((True, idx[on_line]))
        stack.append((False, idx[c[:, axis] > mid]))
        stack.append((False, idx[c[:, axis] < mid]))
    rank = np.empty(P.shape[0], dtype=np.int64)
    rank[np.concatenate(order)] = np.arange(P.shape[0])
    if last is None:
        return np.argsort(rank[where], kind="stable")
    block = np.empty(P.shape[0], dtype=np.int64)
    block[np.concatenate(order)] = np.repeat(np.arange(len(order)), [len(o) for o in order])
    return np.lexsort((rank[where], np.asarray(last, dtype=np.int64), block[where]))


def _first_index(where: np.ndarray, n: int) -> np.ndarray:
    """Index of the first occurrence of each group ``0 .. n-1`` in ``where``."""
    first = np.full(n, where.size, dtype=np.int64)
    np.minimum.at(first, where, np.arange(where.size))
    return first


class DirectSolver:
    """Sparse LU of ``A`` (SuperLU), reusable for ``A x = b`` and ``A^T x = b``.

    coords : optional integer grid positions ``(m, 2)`` of the unknowns, for
    the nested-dissection ordering; without them SuperLU's MMD(A^T + A) is used.
    With a nested-dissection ordering SuperLU keeps the diagonal pivot unless
    it is below 1e-6 of its column's largest entry, which keeps the ordering's
    low fill (a larger threshold is scale-sensitive: with strong Brinkman
    friction it pivots the fill up tenfold); saddle-point systems need their
    pressures ordered last within each block (``nested_dissection(..., last=...)``).
    Each solve checks its residual and refines iteratively (at most twice)
    when it exceeds ``refine_tol`` relative to ``|b|``.
    """

    refine_tol = 1e-12

    def __init__(self, A: sp.spmatrix, coords: np.ndarray | None = None, perm: np.ndarray | None = None):
        A = sp.csc_matrix(A)
        self.A = A
        if perm is None and coords is not None:
            perm = nested_dissection(coords)
        self.perm = perm
        try:
            if perm is None:
                self._lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A")
            else:
                self._lu = spla.splu(A[perm][:, perm].tocsc(), permc_spec="NATURAL",
                                     diag_pivot_thresh=1e-6)
        except RuntimeError as err:        # "Factor is exactly singular"
            raise NumericalError(f"sparse LU failed: {err}",
                                 {"size": A.shape[0], "nnz": A.nnz}) from None
        self.shape = A.shape
        self.dtype = A.dtype

    def _raw(self, b: np.ndarray, trans: str) -> np.ndarray:
        if self.perm is None:
            return self._lu.solve(b, trans=trans)
        x = np.empty_like(b, dtype=np.result_type(b, self.dtype))
        x[self.perm] = self._lu.solve(np.ascontiguousarray(b[self.perm]), trans=trans)
        return x

    def _apply(self, b: np.ndarray, trans: str) -> np.ndarray:
        A = self.A if trans == "N" else self.A.T
        x = self._raw(b, trans)
        bnorm = np.linalg.norm(b)
        for _ in range(2):                               # iterative refinement
            r = b - A @ x
            if not np.all(np.isfinite(x)) or np.linalg.norm(r) <= self.refine_tol * bnorm:
                break
            x = x + self._raw(r, trans)
        if not np.all(np.isfinite(x)):
            raise NumericalError("linear solve produced non-finite values (singular matrix?)",
                                 {"size": self.shape[0]})
        return x

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._apply(b, "N")

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        return self._apply(b, "T")


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
    a dense SVD, seconds for a thousand unknowns). Setting up a hierarchy is
    cheap, so a :class:`RecyclingSolver` builds a new one for every matrix
    (``recycle = False``) instead of preconditioning GMRES with an old one.
    """

    recycle = False

    def __init__(self, A: sp.spmatrix, near_null: np.ndarray | None = None, tol: float = 1e-10,
                 max_iter: int = 500, symmetric: bool = True):
        self.A = sp.csr_matrix(A)
        self.tol, self.max_iter = tol, max_iter
        self.accel = "cg" if symmetric else "gmres"
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

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        if self.accel != "cg":
            return AMGSolver(self.A.T, None, self.tol, self.max_iter, symmetric=False).solve(b)
        return self.solve(b)


def make_solver(A: sp.spmatrix, kind: str = "direct", coords=None, near_null=None, tol=1e-10,
                perm=None, symmetric: bool = True):
    """A reusable solver of kind ``direct`` (LU) or ``amg`` (SPD systems only).

    perm : a precomputed fill-reducing permutation (else computed from ``coords``)
    """
    if kind == "direct":
        return DirectSolver(A, coords=coords, perm=perm)
    if kind == "amg":
        return AMGSolver(A, near_null=near_null, tol=tol, symmetric=symmetric)
    raise ValueError(f"unknown linear solver {kind!r}")


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
            x, ok = self._krylov(A.T.tocsr(), b, self.solver.solve_transpose)
            if ok:
                return x
        self.refresh(A)
        return self.solver.solve_transpose(b)
