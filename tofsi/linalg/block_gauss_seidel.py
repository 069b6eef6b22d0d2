"""Block Gauss-Seidel over the fields' own factorizations: a preconditioner for coupled Jacobians.

A coupled Jacobian in field blocks (two-way FSI: flow ``w``, structure ``u``,
mesh ``x``)

    A = | A_ww  A_wu  A_wx |          M^{-1} r = z, one forward sweep:
        | A_uw  A_uu  A_ux |              z_i = A_ii^{-1} (r_i - sum_{j<i} A_ij z_j)
        | A_xw  A_xu  A_xx |

is preconditioned by its block lower triangle ``M`` (the diagonal blocks
factorized separately, each with its field's fill-reducing ordering). The
fields' own systems are much cheaper to factorize than the monolithic one:
the couplings ``A_wx`` (the flow's shape derivative) and ``A_uw`` (the fluid
load) add fill that the separate factors never see (at 3200 elements of the
headline scene, 6.7 M factor entries against 13.4 M, and a quarter of the
time). GMRES on ``A`` with ``M`` converges in the number of iterations the
coupling's strength asks (8 to 1e-10 there); the solution is that of ``A``,
to the Krylov tolerance.

``A^T x = b`` (adjoints) is preconditioned by the same factors: ``M^T`` is
block upper triangular, so its sweep runs backwards over the fields with the
transposed diagonal solves and the transposed lower blocks of ``A``.

The class has the interface of :class:`tofsi.linalg.AMGSolver` (``exact =
False``, :meth:`preconditioner`, :meth:`solve`, :meth:`solve_transpose`), so
a :class:`tofsi.linalg.RecyclingSolver` keeps it for a sequence of nearby
Jacobians (Newton iterates) until it goes stale.
"""

from __future__ import annotations

import logging
from itertools import pairwise

import numpy as np

from tofsi.core.errors import NumericalError
from tofsi.linalg.backends import canonical_csr
from tofsi.linalg.block_matrix import BlockMatrix
from tofsi.linalg.direct import DirectSolver
from tofsi.linalg.recycling import flexible_gmres
from tofsi.linalg.solver_kind import GMRES_RESTART, SolverKind

log = logging.getLogger(__name__)


class BlockGaussSeidel(SolverKind):
    """Block lower-triangular preconditioner of a field-block matrix, and GMRES with it.

    A : the square matrix, a :class:`~tofsi.linalg.BlockMatrix` of the fields' blocks, or an
        assembled sparse matrix whose unknowns are stacked field after field (then ``sizes``)
    sizes : the fields' sizes, in the order of ``A``'s unknowns (only for an assembled ``A``)
    orderings : per field, a fill-reducing permutation of its unknowns (or None)
    direct : ``(matrix, perm) -> DirectSolver`` on the model's backend (default: the process's)

    ``origins[i]``: the ``origin`` of the matrix whose diagonal block ``i`` was factorized
    (:attr:`BlockMatrix.origin`; None where unknown), so that the factors can be named by what
    they were made of and made again from it (a resumed optimization,
    :mod:`tofsi.optimization.carried_factors`).
    """

    follows_matrix = True      # preconditioner(transpose, matrix): the sweep takes the matrix's couplings
    setup_iterations = 15      # factorizing the diagonal blocks costs about 15 GMRES iterations (measured on
                               # the large scene: 13 sweeps at 80 x 40, 16 at 160 x 80)
    refactor_iterations = 3    # factorizing the small blocks again (refactor_small_blocks): about 3
                               # sweeps (0.127 s against 46 ms at 160 x 80, 19 against 10 ms at 80 x 40)

    def __init__(self, A, sizes=None, orderings=None, tol: float = 1e-10, max_iter: int = 200,
                 direct=None):
        if not isinstance(A, BlockMatrix):
            if sizes is None:
                raise ValueError("an assembled matrix needs the block sizes")
            A = BlockMatrix.from_sparse(A, sizes)
        elif sizes is not None and tuple(sizes) != A.sizes:
            raise ValueError(f"block sizes {list(sizes)} are not the matrix's {list(A.sizes)}")
        self.direct = direct or (lambda M, perm=None: DirectSolver(M, perm=perm))
        self.A, self.tol, self.max_iter, self.shape = A, tol, max_iter, A.shape
        self.starts = A.starts
        n = len(A.sizes)
        self.orderings = list(orderings or [None] * n)
        self.diagonal = [self.direct(canonical_csr(A.blocks[(i, i)]), perm=self.orderings[i]) for i in range(n)]
        self.origins = [A.origin] * n
        self.lower, self.upper_t = self._couplings(A)
        self.memory_bytes = sum(d.memory_bytes for d in self.diagonal)
        self._solve = [d.preconditioner(False) for d in self.diagonal]      # triangular solves only
        self._solve_t = [d.preconditioner(True) for d in self.diagonal]

    def refactor_small_blocks(self, A: BlockMatrix) -> list[int]:
        """Factorize again, from the nearby matrix ``A`` (in blocks of these sizes), every diagonal
        block smaller than the largest (the structure's and the mesh's beside the flow's), keeping
        the largest's factors; returns the blocks refactorized. Far from a Newton's solution the
        small fields' tangents change most from one iterate to the next (a finite-strain structure,
        a hyperelastic mover) while the largest, dearest one changes little: the large scene's step
        to its full inflow at 80 x 40 took GMRES 9 iterations per decade with the first iterate's
        factors, 2-4 with the small blocks' refactorized (6642 unknowns each, against 29403). A
        failed factorization leaves the preconditioner unusable (its old factors released first)."""
        if not isinstance(A, BlockMatrix) or A.sizes != self.A.sizes:
            raise ValueError("refactor_small_blocks needs a block matrix of the preconditioner's block sizes")
        largest = max(A.sizes)
        small = [i for i, size in enumerate(A.sizes) if size < largest]
        for i in small:                     # the old factors released first (their memory reused)
            self.memory_bytes -= self.diagonal[i].memory_bytes
            self.diagonal[i] = self._solve[i] = self._solve_t[i] = None
            self.diagonal[i] = self.direct(canonical_csr(A.blocks[(i, i)]), perm=self.orderings[i])
            self.origins[i] = A.origin
            self.memory_bytes += self.diagonal[i].memory_bytes
            self._solve[i] = self.diagonal[i].preconditioner(False)
            self._solve_t[i] = self.diagonal[i].preconditioner(True)
        return small

    @staticmethod
    def _couplings(A: BlockMatrix):
        """Per block row ``i`` of ``A``: its blocks left of the diagonal ``A_ij, j < i`` (``M``'s
        sweep) and the transposes ``(A_ji)^T, j > i`` (``M^T``'s upper part)."""
        n = len(A.sizes)
        return ([A.sub((i,), range(i)) for i in range(n)],
                [A.sub(range(i + 1, n), (i,)).T for i in range(n)])

    def _sweep(self, r: np.ndarray, lower=None) -> np.ndarray:
        """``M^{-1} r``: forward block substitution."""
        lower = lower or self.lower
        z = np.empty_like(r)
        for i, (a, b) in enumerate(pairwise(self.starts)):
            rhs = r[a:b] - lower[i] @ z[:a] if lower[i] else r[a:b]
            z[a:b] = self._solve[i](rhs)
        return z

    def _sweep_transpose(self, r: np.ndarray, upper_t=None) -> np.ndarray:
        """``M^{-T} r``: backward block substitution with the transposed blocks."""
        upper_t = upper_t or self.upper_t
        z = np.empty_like(r)
        for i in reversed(range(len(self._solve))):
            a, b = self.starts[i], self.starts[i + 1]
            rhs = r[a:b] - upper_t[i] @ z[b:] if upper_t[i] else r[a:b]
            z[a:b] = self._solve_t[i](rhs)
        return z

    def preconditioner(self, transpose: bool = False, matrix: BlockMatrix | None = None):
        """``b -> M^{-1} b`` (or ``M^{-T} b``), for GMRES on this or a nearby matrix. ``matrix``:
        that nearby matrix (``A^T`` where ``transpose``), in blocks of these sizes: the sweep then
        takes its blocks off the diagonal (the current couplings, cheap: products) with these
        diagonal factors, and multiplies the vectors the Krylov product after it multiplies."""
        if isinstance(matrix, BlockMatrix) and matrix.sizes == self.A.sizes:
            lower, upper_t = self._couplings(matrix.T if transpose else matrix)
            if transpose:
                return lambda r: self._sweep_transpose(r, upper_t)
            return lambda r: self._sweep(r, lower)
        return self._sweep_transpose if transpose else self._sweep

    def _gmres(self, A, b: np.ndarray, apply) -> np.ndarray:
        """GMRES to ``tol`` relative to ``|b|``, or NumericalError."""
        bnorm = float(np.linalg.norm(b))
        x, its = flexible_gmres(A, b, apply, self.tol * bnorm, self.max_iter, GMRES_RESTART)
        relative = float(np.linalg.norm(b - A @ x)) / max(bnorm, 1e-300)
        log.info("block-Gauss-Seidel GMRES: %d iterations, residual %.2e relative to |b|", its, relative)
        if not np.all(np.isfinite(x)) or relative > 1.01 * self.tol:
            raise NumericalError("block-Gauss-Seidel GMRES did not converge",
                                 {"iterations": its, "relative_residual": relative, "size": A.shape[0]})
        return x

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``A^-1 b`` by GMRES to ``tol``; the LU of the whole of ``A`` when GMRES fails (and ``A``
        can be assembled: else the failure)."""
        try:
            return self._gmres(self.A, b, self._sweep)
        except NumericalError as err:
            if not self.A.assembled:
                raise
            log.warning("%s; factorizing the whole matrix instead", err)
            return self.direct(self.A.tocsr()).solve(b)

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        """``A^-T b``, as :meth:`solve`."""
        try:
            return self._gmres(self.A.T, b, self._sweep_transpose)
        except NumericalError as err:
            if not self.A.assembled:
                raise
            log.warning("%s; factorizing the whole matrix instead", err)
            return self.direct(self.A.tocsr()).solve_transpose(b)
