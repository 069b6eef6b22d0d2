"""Smoothed-aggregation AMG with CG (or GMRES) for the structure and mesh-motion systems, and a
smoothed-aggregation setup that does not copy the fine matrix.

:func:`smoothed_aggregation` builds pyamg's default smoothed-aggregation
hierarchy (symmetric strength of connection at ``theta = 0``, standard
aggregation, candidates improved by four block Gauss-Seidel sweeps, one
Jacobi smoothing step of the tentative prolongator ``T`` with ``omega =
4/3``) with the finest level's intermediates formed without copies of ``A``:

* the strength of connection at ``theta = 0`` keeps every stored entry, and
  the aggregation reads only its pattern, so ``A``'s own pattern is passed
  (pyamg forms the scaled ``|A|``: one copy of ``A`` held and two more
  transient);
* the smoothed prolongator ``P = T - (omega / rho(D^{-1} A)) D^{-1} A T`` is
  formed as ``A T`` with its rows scaled afterwards (pyamg forms ``D^{-1} A``
  and ``omega / rho D^{-1} A``: two copies of ``A``), ``rho`` estimated by
  pyamg's Arnoldi iteration on the operator ``x -> D^{-1} A x``.

The hierarchy is pyamg's to round-off (the same aggregates, ``P`` to 1e-15
relative, the same iterations); for the flow's velocity block at 16 200
elements the setup's peak above what was held before it falls from 9.9 to
2.7 kB per element, 1.3 of which it keeps (nonsymmetric: 14.1 to 6.7, a
transposed copy of ``A`` among them; ``docs/parallel.md``). The coarser
levels (a few thousand unknowns) are pyamg's own.

The cycle smooths with pyamg's symmetric block Gauss-Seidel sweeps (forward
and backward) before and after the coarse correction, or, with ``ONE_SWEEP``,
one forward sweep before and one backward sweep after: half the smoothing
work, and still a symmetric operator for a symmetric ``A`` (the post-smoother
is the pre-smoother's adjoint). The flow's block preconditioner
(:mod:`tofsi.linalg.iterative`) takes ``ONE_SWEEP``: measured on the
velocity block at 180 x 90 elements (130 682 unknowns, one thread), a
V-cycle 16.5 ms instead of 26.0 ms through pyamg's ``solve`` (11.4-11.8 against
17.8-18.6 ms by :func:`v_cycle`, which applies it without pyamg's residual norms), the adjoint's transposed GMRES 70
iterations instead of 65 (1.98 s instead of 2.63 s), the Newton steps' GMRES
1-4 iterations more per solve of 15-30 (0.48-0.92 s instead of 0.55-0.94 s);
weighted Jacobi (two sweeps each side) and 2 x 2 block Gauss-Seidel were
slower. On sharp designs the gain shrinks: at 180 x 90 the forward solve
still gains 4-10 % and the transposed one nothing, at 80 x 40 the transposed
solve takes 15 % longer (``docs/parallel.md``, "Smoothing"). :class:`AMGSolver` (the structure, the movers) keeps the symmetric
sweeps: with ``ONE_SWEEP`` its CG took 258 iterations instead of 191 on a
random gray 180 x 90 structure, for the same time (0.82 s against 0.88 s).
"""

from __future__ import annotations

import logging
from contextlib import contextmanager

import numpy as np
import pyamg
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from pyamg.aggregation.aggregate import standard_aggregation
from pyamg.aggregation.tentative import fit_candidates
from pyamg.multilevel import MultilevelSolver
from pyamg.relaxation.smoothing import change_smoothers
from pyamg.relaxation.utils import relaxation_as_linear_operator
from pyamg.util.linalg import approximate_spectral_radius
from pyamg.util.utils import get_diagonal, scale_rows

from tofsi.core.errors import NumericalError
from tofsi.linalg.solver_kind import SolverKind

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


OMEGA = 4.0 / 3.0                                      # pyamg's Jacobi prolongation smoothing weight
IMPROVE = ("block_gauss_seidel", {"sweep": "symmetric", "iterations": 4})   # pyamg's candidate improvement
SYMMETRIC_SWEEPS = (("block_gauss_seidel", {"sweep": "symmetric"}),) * 2   # pyamg's pre- and post-smoother
ONE_SWEEP = (("block_gauss_seidel", {"sweep": "forward"}),      # one forward Gauss-Seidel sweep before the
             ("block_gauss_seidel", {"sweep": "backward"}))     # coarse correction, one backward after
MAX_COARSE = 300
SPECTRAL_SEED = 0   # the seed of np.random while a hierarchy is built (below)


def _improved(A, B: np.ndarray) -> np.ndarray:
    """Near-null candidates ``B`` after pyamg's four symmetric block Gauss-Seidel sweeps on ``A x = 0``."""
    return relaxation_as_linear_operator(IMPROVE, A, np.zeros((A.shape[0], 1), dtype=A.dtype)) @ B


def _smoothed(A, T):
    """``T - (omega / rho) D^{-1} A T``, ``rho`` the spectral radius of ``D^{-1} A`` (pyamg's
    Jacobi prolongation smoother), without forming ``D^{-1} A``."""
    d_inv = get_diagonal(A, inv=True)
    DA = spla.LinearOperator(A.shape, matvec=lambda x: d_inv.reshape(-1, *([1] * (x.ndim - 1))) * (A @ x),
                                  dtype=A.dtype)
    weight = (OMEGA / approximate_spectral_radius(DA)) * d_inv
    AT = sp.csr_array(A @ T)
    AT = scale_rows(AT, weight, copy=False)
    return T - AT


def v_cycle(ml: MultilevelSolver):
    """One V-cycle ``b -> x`` of the hierarchy ``ml`` from ``x = 0``: pyamg's
    ``ml.solve(b, maxiter=1, cycle="V")`` (what ``ml.aspreconditioner()`` applies), bitwise,
    without the two residual norms ``|b - A x|`` that its ``solve`` takes before and after the
    cycle to test convergence -- two products with the finest matrix per application that a
    preconditioner never reads (measured at 180 x 90 on the flow's velocity block, 130 682
    unknowns, one thread: 16.8 ms a cycle through pyamg, 10.4 ms here). A loop down the levels
    and back up, not a recursive closure: a function that refers to itself through its closure
    is a reference cycle, and would keep the hierarchy alive until the cyclic garbage collector
    ran (measured: 0.24 GB more peak at 180 x 90 with the flow's hierarchies of past designs)."""
    levels, coarse_solver = ml.levels, ml.coarse_solver

    def apply(b: np.ndarray) -> np.ndarray:
        b = np.ravel(np.asarray(b, dtype=np.result_type(b.dtype, levels[0].A.dtype)))
        if len(levels) == 1:
            return np.asarray(coarse_solver(levels[0].A, b))
        xs, bs = [], []
        for level in levels[:-1]:                      # down: pre-smooth from zero, restrict the residual
            x = np.zeros_like(b)
            level.presmoother(level.A, x, b)
            xs.append(x)
            bs.append(b)
            b = level.R @ (b - level.A @ x)
        x = np.asarray(coarse_solver(levels[-1].A, b), dtype=b.dtype)
        for level, fine_x, fine_b in zip(levels[-2::-1], xs[::-1], bs[::-1], strict=True):   # up: correct, post-smooth
            fine_x += level.P @ x
            level.postsmoother(level.A, fine_x, fine_b)
            x = fine_x
        return x
    return apply


@contextmanager
def _seeded_random():
    """np.random seeded with ``SPECTRAL_SEED`` inside, the caller's state restored after: pyamg
    starts every level's spectral radius estimate (the prolongation smoother's weight) from
    ``np.random.rand``, so that an unseeded hierarchy, and every iterative solve with it, differs
    from run to run in the third digit of its residuals."""
    outer = np.random.get_state()
    np.random.seed(SPECTRAL_SEED)
    try:
        yield
    finally:
        np.random.set_state(outer)


def smoothed_aggregation(A, B: np.ndarray | None = None, symmetric: bool = True,
                         smoothers: tuple = SYMMETRIC_SWEEPS) -> MultilevelSolver:
    """pyamg's ``smoothed_aggregation_solver(A, B, symmetry, max_coarse=300,
    coarse_solver="splu")`` with the finest level built without copies of ``A``
    (module docstring); ``A`` CSR with sorted indices, kept as level 0; ``smoothers``
    the (pre, post) smoothers of its cycle: pyamg's symmetric sweeps, or ``ONE_SWEEP``.
    The same hierarchy every run (:func:`_seeded_random`)."""
    with _seeded_random():
        ml = _smoothed_aggregation(A, B, symmetric)
    change_smoothers(ml, *smoothers)
    return ml


def _smoothed_aggregation(A, B, symmetric: bool) -> MultilevelSolver:
    A = sp.csr_array(A)
    n = A.shape[0]
    B = np.ones((n, 1)) if B is None else np.asarray(B, dtype=A.dtype).reshape(n, -1)
    symmetry = "symmetric" if symmetric else "nonsymmetric"
    if n <= MAX_COARSE:
        return pyamg.smoothed_aggregation_solver(A, B=B, symmetry=symmetry, max_coarse=MAX_COARSE,
                                                 coarse_solver="splu")
    A.symmetry = symmetry
    aggregates = standard_aggregation(sp.csr_array((A.data, A.indices, A.indptr), shape=A.shape))[0]
    fine = MultilevelSolver.Level()
    fine.A, fine.B = A, _improved(A, B)
    T, B_coarse = fit_candidates(aggregates, fine.B)
    fine.P = _smoothed(A, T)
    if symmetric:
        fine.R = fine.P.T
        B_left = None
    else:
        AH = A.T.tocsr()
        fine.BH = _improved(AH, B)
        TH, B_left = fit_candidates(aggregates, fine.BH)
        fine.R = _smoothed(AH, TH).T
        del AH, TH
    del T, aggregates
    coarse = fine.R @ A @ fine.P
    rest = pyamg.smoothed_aggregation_solver(coarse, B=B_coarse, BH=B_left, symmetry=symmetry,
                                             improve_candidates=None,        # pyamg improves the finest only
                                             max_coarse=MAX_COARSE, max_levels=9, coarse_solver="splu")
    return MultilevelSolver([fine] + rest.levels, coarse_solver="splu")


class AMGSolver(SolverKind):
    """Smoothed-aggregation AMG (pyamg) with CG for symmetric positive definite ``A``.

    near_null : near-null-space vectors (rigid-body modes for elasticity). The
    coarsest level is solved by sparse LU (pyamg's default pseudo-inverse is
    a dense SVD, seconds for a thousand unknowns). A :class:`RecyclingSolver`
    keeps a hierarchy for a sequence of nearby matrices, one V-cycle of it
    preconditioning each (:meth:`preconditioner`), until it goes stale.
    """

    linear_preconditioner = True    # a V-cycle is one fixed linear operator (GMRES(m) in RecyclingSolver)
    setup_iterations = 12      # a hierarchy costs about 12 preconditioned CG iterations to build

    def __init__(self, A: sp.spmatrix, near_null: np.ndarray | None = None, tol: float = 1e-10,
                 max_iter: int = 500, symmetric: bool = True):
        self.A = sp.csr_matrix(A)
        self.tol, self.max_iter = tol, max_iter
        self.accel = "cg" if symmetric else "gmres"
        self.symmetric = symmetric
        self._ml = smoothed_aggregation(self.A, near_null, symmetric)
        self._cycle = v_cycle(self._ml)
        self.shape = A.shape

    def solve(self, b: np.ndarray) -> np.ndarray:
        residuals: list[float] = []
        n = self.shape[0]
        M = spla.LinearOperator((n, n), matvec=self._cycle, dtype=self.A.dtype)
        krylov = pyamg.krylov.cg if self.accel == "cg" else pyamg.krylov.gmres
        x, _ = krylov(self.A, b, tol=self.tol, maxiter=self.max_iter, M=M, residuals=residuals)
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
        return self._cycle

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        if self.accel != "cg":
            return AMGSolver(self.A.T, None, self.tol, self.max_iter, symmetric=False).solve(b)
        return self.solve(b)
