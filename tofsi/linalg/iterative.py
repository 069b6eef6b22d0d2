"""Block-preconditioned Krylov solves of saddle-point systems (the Q2/Q1 Brinkman Navier-Stokes Jacobian).

The constrained flow Jacobian, velocities first, pressures after,

    J = | A   B^T |       A  (n_v x n_v): viscous + convective (Newton) + Brinkman block
        | B   0   |       B  (n_p x n_v): -int M div N, the discrete divergence

is preconditioned by its block upper triangle with approximate blocks

    P = | A~  B^T |       P^{-1} [f; g]:   p = S~^{-1} g,   u = A~^{-1} (f - B^T p)
        | 0   S~  |

(Elman, Silvester & Wathen 2014, ch. 9). ``A~^{-1}`` is one V-cycle of
smoothed-aggregation AMG (pyamg) on ``A`` with one Gauss-Seidel sweep on
each side (:data:`tofsi.linalg.amg.ONE_SWEEP`; the iteration counts quoted
below for 80 x 40 were measured with pyamg's symmetric sweeps, which take
5-30 % fewer iterations at about 1.6 times the cost of a cycle;
``docs/parallel.md``, "Smoothing");
``S~^{-1}`` approximates the
inverse Schur complement ``S = -B A^{-1} B^T`` by the Cahouet-Chabard sum

    -S~^{-1} = M_mu^{-1} + L_alpha^{-1},
    M_mu    = lumped Q1 pressure mass / mu                       (viscous limit),
    L_alpha = B (alpha M_v)^{-1} B^T  (lumped Q2 mass, per element) (Darcy limit),

exact in the two limits of the Brinkman range: in fluid (``alpha h^2 << mu``)
``S ~ -mu^{-1} M_p``, in solid (``alpha h^2 >> mu``) ``S ~ -B (alpha M_v)^{-1} B^T``,
a pressure Laplacian with coefficient ``1/alpha``. ``alpha`` is floored at
``FLOOR mu / h^2`` per element so ``L_alpha``'s inverse vanishes in fluid
instead of dividing by zero. The comparison with the weighted mass
``M / (mu + alpha h^2)`` and with SIMPLE's ``B diag(A)^{-1} B^T`` is in
``docs/parallel.md``.

Convergence is measured in the norm of the system scaled symmetrically by
``D^{-1/2}``, ``D = (|diag A|, diag S~)``: velocity rows by the block's
diagonal, pressure rows by ``1 / (1/M_mu + 1/diag L_alpha)``. In the plain
Euclidean norm the Brinkman rows (``alpha h^2`` up to 1e6 times the viscous
ones) dominate and the pressure in solid regions, where ``S`` is ``1/alpha``
small, is left inaccurate (measured at alpha_max = 1e5, relative residual
1e-10: pressure error 6e-4 plain, 2e-6 scaled, against the LU solution).

The transpose ``J^T = [[A^T, B^T], [B, 0]]`` (adjoints) is preconditioned
by ``P^T`` (block lower triangular: ``u = A~^{-T} f``, ``p = S~^{-1} (g - B u)``)
with, for ``A~^{-T}``, the hierarchy of ``A`` itself when ``A`` is nearly
symmetric (``|A - A^T|_F <= SHARED_HIERARCHY_ASYMMETRY |A|_F``: the convection
is weak next to the viscous and Brinkman terms) and otherwise one built on
``A^T`` (on first use). A nearly symmetric ``A`` gets pyamg's symmetric
smoothed aggregation (``R = P^T``): the same iterations at 80 x 40 (94 / 55
forward / transposed) and a setup that peaks at 10 instead of 14 kB per
element (it smooths no second prolongator with ``A^T``). Measured on the beam scene at 80 x 40 elements,
transposed FGMRES iterations with the hierarchy of ``A^T`` / of ``A``: Re 1
(asymmetry 0.005) 98 / 99 and 153 / 154 (gray and 0/1 design), Re 10
(asymmetry 0.048) 126 / 210 and 185 / 356.

In ``P^T`` the Darcy part is weighted, ``-S~^{-1} = M_mu^{-1} + c L_alpha^{-1}``
with ``c`` = :data:`TRANSPOSE_DARCY_WEIGHT` (2.5): one V-cycle of ``L_alpha``
under-corrects its smooth modes, and the weight makes up for it. Measured
on the adjoint's systems of the beam scene at 180 x 90 (designs 1-4 of
``benchmarks/optimize.py``, to 1e-6): transposed GMRES iterations at ``c`` =
1 / 1.5 / 2 / 2.5 / 3 / 4 / 6: 49 / 45 / 43 / 43 / 43 / 44 / 49, the
solution's error against a 1e-11 solve 4.2 / 2.9 / 2.1 / 1.6 / 2.8 / 5.7 /
6.1e-6; with ``L_alpha`` by its LU the weight does nothing (40 iterations at
``c`` = 1 to 3, 0.13 s more setup). The forward ``P`` keeps ``c = 1`` (its
Newton iterates and so the optimization's path stay as they were).

The transposed solves are the adjoint's and converge to ``transpose_tol``
(:data:`TRANSPOSE_TOL`, 3e-6), the tolerance the gradient needs. An adjoint
residual ``r`` leaves an error ``r^T dw/drho`` in the gradient: measured
against the LU gradient on the beam scene (compliance; random and uniform
designs), the gradient's relative error at transposed tolerances 1e-8 / 1e-7
/ 1e-6 / 1e-5 was 0.6-1.2e-7 / 1.3-1.7e-6 / 1.1-1.9e-5 / 1.0-1.6e-4 at 40 x 20
elements (the dissipation 0.1-1.2e-7 / - / 5.0e-6 / 0.5-1.1e-4), 0.4-7.4e-8 /
0.8-4.3e-7 / 0.4-7.6e-6 / 0.5-3.8e-5 at 90 x 45 and 0.7-1.5e-8 / 0.9-3.8e-7
/ 1.5-1.7e-6 / 2.1-4.7e-5 at 180 x 90, for 70-77 / 58-64 / 49-54 / 39-46
transposed GMRES iterations at 180 x 90 (with ``c = 1``; the error is 1-20 times the
tolerance: the compliance gradient is a difference of flow and structure
parts several times its size). What MMA needs is read from whole
optimizations against the direct path's (beam scene, 40 x 20, 60 iterations
over three continuation stages): with ``c = 1``, at 1e-8 / 1e-6 / 1e-5 the final objective
differed by 8.7e-8 / 5.7e-6 / 7.4e-5 relative and the final design by 3e-6 /
3.6e-4 / 2.7e-3 at most, against the stopping rule's design change
``optimizer.tol_change`` (2e-3): 1e-6 ended at the same design to five times
below what the optimizer resolves, 1e-5 did not. The weight ``c = 2.5``
makes each solve more accurate at the same residual (its error against a
1e-11 solve 4.2e-6 -> 1.6e-6 at 1e-6), so the same accuracy comes at a looser
one: at 1e-6 / 1.5e-6 / 2e-6 / 3e-6 / 4e-6 / 5e-6 the final design differs by
1.4 / 1.6 / 1.6 / 2.8 / 3.3 / 3.6e-4 and the objective by 0.02 / 0.1 / 0.45 /
1.2 / 1.0 / 0.45e-5; the gradient against the LU's at 1e-6 / 2e-6 / 3e-6 /
5e-6 is 3.8-9.7e-6 / 1.1-1.2e-5 / 1.2-2.4e-5 / 2.7-4.8e-5 at 40 x 20 and
0.7-1.1e-6 / 2.1-2.7e-6 / 2.9-3.1e-6 / - at 180 x 90 (two random designs
and a uniform one, 2026-11-27). So 3e-6: the final design seven times below what the
optimizer resolves (1e-6 five times with ``c = 1``), the gradient at most
2.5e-5 off at 40 x 20 (1e-6 with ``c = 1``: 1.1-1.9e-5), and 38 transposed GMRES
iterations at 180 x 90 instead of 43 (about 10 per decade there: 1e-6 / 2e-6 /
3e-6 / 5e-6 take 42-43 / 39-40 / 38 / 36 on ``benchmarks/optimize.py``'s six first
designs). A scene that
needs the gradient to the LU's precision sets ``solver.adjoint_tol`` (1e-8:
1e-7 off); ``tofsi check-gradients`` asks for 1e-10 and a tighter flow Newton
(:func:`tofsi.commands.check_gradients.checked_scene`).

:class:`BlockSaddlePreconditioner` has the interface of
:class:`tofsi.linalg.AMGSolver` (``exact = False``, :meth:`preconditioner`,
:meth:`solve`, :meth:`solve_transpose`), so a :class:`tofsi.linalg.RecyclingSolver`
keeps one for the Newton steps of a solve and the adjoint's transposed solve,
building a new one when it goes stale.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tofsi.core.errors import NumericalError
from tofsi.linalg.amg import ONE_SWEEP, smoothed_aggregation, v_cycle
from tofsi.linalg.solver_kind import SolverKind
from tofsi.linalg.block_matrix import SaddlePointMatrix
from tofsi.linalg.krylov import gmres

log = logging.getLogger(__name__)
FLOOR = 1e-2            # alpha >= FLOOR mu / h^2 in L_alpha (measured: 1e-2 and 1 give the same counts)
SHARED_HIERARCHY_ASYMMETRY = 1e-2     # below it the hierarchy of A serves A^T (module docstring)
TRANSPOSE_TOL = 3e-6                  # the adjoint's transposed solves: what the gradient needs (module docstring)
TRANSPOSE_DARCY_WEIGHT = 2.5          # c L_alpha^{-1} in P^T's S~ (module docstring): 49 -> 43 iterations
PRESSURE_SOLVERS = ("amg", "direct")
RESTART = 30            # GMRES(30): the iterations of FGMRES(50) at 80 x 40 (94 / 55 against 93 / 56,
                        # forward / transposed), a third of its basis; GMRES(20) needs 124 forward


def velocity_near_null(n_velocity: int) -> np.ndarray:
    """The two constant modes ``(n_v, 2)`` of node-interleaved plane velocities (AMG's near null space)."""
    return np.kron(np.ones((n_velocity // 2, 1)), np.eye(2))


def asymmetry(A: sp.csr_matrix, chunk: int = 1 << 20) -> float:
    """``|A - A^T|_F / |A|_F`` holding one transposed copy of ``A`` (``A - A^T`` and its
    squares, 12 kB per element of the flow at once, are not formed): on a structurally
    symmetric pattern with sorted indices, ``A^T``'s data is aligned with ``A``'s."""
    A.sort_indices()
    At = A.T.tocsr()
    At.sort_indices()
    if not (np.array_equal(A.indptr, At.indptr) and np.array_equal(A.indices, At.indices)):
        return float(spla.norm(A - At) / max(spla.norm(A), 1e-300))
    squares = sum(float(np.sum((A.data[k:k + chunk] - At.data[k:k + chunk]) ** 2))
                  for k in range(0, A.data.size, chunk))
    return float(np.sqrt(squares) / max(np.linalg.norm(A.data), 1e-300))


def _amg(M: sp.csr_matrix, near_null=None, symmetric: bool = False):
    """Smoothed aggregation on ``M`` whose V-cycle smooths by one Gauss-Seidel sweep on each side
    (:data:`tofsi.linalg.amg.ONE_SWEEP`: a quarter less time per GMRES iteration at 180 x 90)."""
    return smoothed_aggregation(M, near_null, symmetric, ONE_SWEEP)


class BlockSaddlePreconditioner(SolverKind):
    """Block-triangular preconditioner of a saddle-point matrix, and GMRES(m) with it.

    A : the square matrix ``[[A, B^T], [B, C]]`` with the first ``n_velocity`` unknowns the
        velocities; ``C`` holds only Dirichlet (pinned pressure) identity rows
    mass : ``(n_p,)`` the pressure mass diagonal scaled by ``1/mu`` (``M_mu``)
    darcy_weights : ``(n_v,)`` ``1 / (alpha M_v)``, the inverse friction mass per velocity dof
        (0 on fixed dofs), or None to use ``M_mu`` alone
    fixed : ``(n,)`` bool, the Dirichlet dofs (identity rows and columns of ``A``)
    pressure_solver : ``amg`` (a V-cycle on ``L_alpha``) or ``direct`` (its sparse LU)
    tol, transpose_tol : GMRES tolerances (scaled relative residual) of the solves with ``J``
        and with ``J^T``
    """

    linear_preconditioner = True    # one fixed linear operator: GMRES(m), not FGMRES
    restart = RESTART
    own_krylov = True         # solve_with: GMRES in its own scaled norm
    setup_iterations = 8       # measured: one AMG setup costs about as much as 8 FGMRES iterations

    def __init__(self, A: sp.spmatrix, n_velocity: int, mass: np.ndarray, darcy_weights: np.ndarray | None,
                 fixed: np.ndarray, pressure_solver: str = "amg", tol: float = 1e-10,
                 transpose_tol: float = TRANSPOSE_TOL, max_iter: int = 400):
        if pressure_solver not in PRESSURE_SOLVERS:
            raise ValueError(f"pressure_solver {pressure_solver!r}: allowed {PRESSURE_SOLVERS}")
        nv = n_velocity
        self.shape, self.tol, self.max_iter = A.shape, tol, max_iter
        self.transpose_tol = transpose_tol
        self.nv = nv
        self.iterations = 0
        self.fixed_p = np.flatnonzero(np.asarray(fixed)[nv:])
        if isinstance(A, SaddlePointMatrix):                         # its blocks themselves, no copy
            self.A, self.B = A.A, A.B
        else:
            A = sp.csr_matrix(A)
            self.A = A[:nv, :nv].tocsr()                             # (n_v, n_v)
            self.B = A[nv:, :nv].tocsr()                             # (n_p, n_v); the (v, p) block is B^T
        self.pinned = np.zeros(A.shape[0] - nv)                      # (n_p,) C: 1 on pinned pressures
        self.pinned[self.fixed_p] = 1.0
        self.mass = np.array(mass, dtype=float)
        self.mass[self.fixed_p] = np.inf                             # pinned pressures: set apart
        self.asymmetry = asymmetry(self.A)
        nearly_symmetric = self.asymmetry <= SHARED_HIERARCHY_ASYMMETRY
        self._ml = _amg(self.A, velocity_near_null(nv), symmetric=nearly_symmetric)
        self._cycle = v_cycle(self._ml)
        self._cycle_t = self._cycle if nearly_symmetric else None
        self._darcy = None
        if darcy_weights is not None:
            L = (self.B @ sp.diags(darcy_weights) @ self.B.T).tocsr()  # (n_p, n_p) SPD on free pressures
            if self.fixed_p.size:
                keep = np.ones(L.shape[0])
                keep[self.fixed_p] = 0.0
                L = (sp.diags(keep) @ L @ sp.diags(keep) + sp.diags(1.0 - keep)).tocsr()
            self._darcy = self._pressure_inverse(L, pressure_solver)
            darcy_diagonal = np.maximum(L.diagonal(), 1e-300)
        else:
            darcy_diagonal = np.full(self.mass.size, np.inf)
        d_p = 1.0 / (1.0 / self.mass + 1.0 / darcy_diagonal)             # (n_p,) diag of -S~
        d_p[self.fixed_p] = 1.0
        d = np.concatenate([np.abs(self.A.diagonal()), d_p])
        self.scale = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))                # D^{-1/2} (n,)
        self.memory_bytes = self._bytes()

    @staticmethod
    def _pressure_inverse(L: sp.csr_matrix, kind: str):
        if kind == "direct":
            from tofsi.linalg.direct import DirectSolver
            return DirectSolver(L).preconditioner(False)
        return v_cycle(_amg(L, symmetric=True))

    def _bytes(self) -> int:
        total = sum(M.data.nbytes + M.indices.nbytes + M.indptr.nbytes for M in (self.A, self.B))
        for level in self._ml.levels:
            for name in ("A", "P", "R"):
                M = getattr(level, name, None)
                if M is not None and sp.issparse(M):
                    total += M.data.nbytes + M.indices.nbytes + M.indptr.nbytes
        return int(total)

    def _schur(self, g: np.ndarray, darcy_weight: float = 1.0) -> np.ndarray:
        """``S~^{-1} g = -(M_mu^{-1} + c L_alpha^{-1}) g``, ``c = darcy_weight``; pinned
        pressures take ``g`` itself."""
        p = -(g / self.mass)
        if self._darcy is not None:
            p -= darcy_weight * self._darcy(g)
        p[self.fixed_p] = g[self.fixed_p]
        return p

    def _apply(self, r: np.ndarray) -> np.ndarray:
        """``P^{-1} r``: the pressure first, then the velocity with it."""
        nv = self.nv
        p = self._schur(r[nv:])
        u = self._cycle(r[:nv] - self.B.T @ p)
        return np.concatenate([u, p])

    def _apply_transpose(self, r: np.ndarray) -> np.ndarray:
        """``P^{-T} r``: the velocity first (a cycle of ``A``'s hierarchy when ``A`` is nearly
        symmetric, else of ``A^T``'s), then the pressure."""
        nv = self.nv
        if self._cycle_t is None:
            self._cycle_t = v_cycle(_amg(self.A.T.tocsr(), velocity_near_null(self.nv)))
        u = self._cycle_t(r[:nv])
        p = self._schur(r[nv:] - self.B @ u, TRANSPOSE_DARCY_WEIGHT)
        return np.concatenate([u, p])

    def preconditioner(self, transpose: bool = False):
        """``b -> P^{-1} b`` (or ``P^{-T} b``), for Krylov solves with this or a nearby matrix."""
        return self._apply_transpose if transpose else self._apply

    def _gmres(self, M, b: np.ndarray, apply, tol: float) -> np.ndarray:
        """GMRES(m) on ``D^{-1/2} M D^{-1/2} y = D^{-1/2} b``, ``x = D^{-1/2} y`` (same iterates'
        preconditioned operator, the scaled residual norm) to ``tol``."""
        s = self.scale
        Ms = spla.LinearOperator(M.shape, matvec=lambda y: s * (M @ (s * y)), dtype=float)
        bs = s * b
        bnorm = float(np.linalg.norm(bs))
        if bnorm == 0.0:
            return np.zeros_like(b)
        y, its = gmres(Ms, bs, lambda r: apply(r / s) / s, tol * bnorm, self.max_iter, self.restart)
        self.iterations = its
        relative = float(np.linalg.norm(bs - Ms @ y)) / bnorm
        x = s * y
        log.info("block-preconditioned GMRES: %d iterations, scaled residual %.2e relative", its, relative)
        if not np.all(np.isfinite(x)) or relative > 1.01 * tol:
            raise NumericalError("block-preconditioned GMRES did not converge",
                                 {"iterations": its, "relative_residual": relative, "size": M.shape[0]})
        return x

    def solve_with(self, A, b: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``A^{-1} b`` (``A^{-T} b``) for ``A`` this or a nearby matrix (a later Newton iterate's),
        by GMRES with this preconditioner to ``tol`` (``transpose_tol``) in the scaled norm
        (NumericalError otherwise)."""
        if transpose:
            return self._gmres(A.T, b, self._apply_transpose, self.transpose_tol)
        return self._gmres(A, b, self._apply, self.tol)

    def matrix(self) -> SaddlePointMatrix:
        """``J = [[A, B^T], [B, C]]`` from the blocks held (``C`` the pinned pressures'
        identity), as an operator: the assembled matrix is not kept beside its blocks."""
        return SaddlePointMatrix(self.A, self.B, self.pinned)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``J^{-1} b`` by GMRES to ``tol`` relative to ``|D^{-1/2} b|`` (NumericalError otherwise)."""
        return self.solve_with(self.matrix(), b)

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        """``J^{-T} b``, as :meth:`solve` to ``transpose_tol``."""
        return self.solve_with(self.matrix(), b, transpose=True)
