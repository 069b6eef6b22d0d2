"""Incremental linear mesh motion on the updated mesh, its tangent and its reverse sweep.

Shared by the spring mover and the incremental linear-elastic mover: the
prescribed motion is applied in ``N`` increments ``d_k = h_k u`` (equal,
``h_k = 1/N``, or a smaller first one: :func:`schedule`);
increment ``k`` uses the stiffness of the *current* mesh, scaled per quad by
the stiffening factors ``f``, ``K(x_k) = sum_e f_e K0_e(X + x_k)``, and solves

    [[W K_ff + S_c, W K_fp], [0, I]] [dx_f, dx_p] = [S_c d_f, d_p],   x_{k+1} = x_k + dx,

with ``W = 1``, ``S_c = 0`` unless the problem is density-blended
(:mod:`movers.blend`). The stiffness may instead be taken at the increment's
midpoint extrapolated from the increment before,
``y_k = x_k + a_k (x_k - x_(k-1))``, ``a_k = h_k / (2 h_(k-1))``
(:class:`IncrementKernel`'s ``extrapolation``): the same one solve per
increment, but the path's error falls like ``1/N^2`` instead of ``1/N``, so
fewer increments reach the same mesh (the first, at its start, is first
order: a smaller first one, :class:`IncrementKernel`'s ``first``). Below,
``x_k`` in ``K(x_k)`` and its shape derivative then reads ``y_k``, whose
tangent is ``(1 + a_k) x_dot_k - a_k x_dot_(k-1)`` and whose adjoint goes to
``x_k`` and ``x_(k-1)`` likewise. The pattern (element dofs, Dirichlet mask) is built
once; each increment only recomputes element matrices. Consecutive
increments' matrices differ by O(1/N), so a
:class:`~tofsi.linalg.RecyclingSolver` solves most of them with a few GMRES
iterations preconditioned by an earlier factorization.

Reverse sweep (vector-Jacobian product of ``u, f, s -> x``): with ``xbar`` the
adjoint of ``x_N``, for ``k = N-1 .. 0``

    (W K_ff + S_c)^T lam_f = xbar_f,   lam_p = xbar_p - (K^T W lam_f)_p,
    dbar_k,f = S_c lam_f,   dbar_k,p = lam_p,   fbar_e -= (W lam)_e . K0_e dx_e,
    sbar_i -= lam_i . (c_i (dx_i - d_i) - (K dx)_i),
    xbar -= d/dx_k [(W lam_f) . K(x_k) dx]        (shape derivative, complex step),

and ``ubar = sum_k h_k dbar_k``. Tangent sweep (Jacobian-vector product of ``u -> x``,
``f`` and ``s`` held): for ``k = 0 .. N-1`` from ``x_dot_0 = 0``, ``d_dot = h_k u_dot``,

    (W K_ff + S_c) dx_dot_f = [W (-K_fp d_dot_p - d/dx_k[K(x_k) dx] x_dot_k) + S_c d_dot]_f,
    dx_dot_p = d_dot_p,   x_dot_(k+1) = x_dot_k + dx_dot.

Both sweeps are linear in their input; what they need of each increment (its
matrices, a factorization of its system and the shape derivative of its
forces) is built once per move (:class:`IncrementDerivatives`), so a Newton
that applies the tangent once per Krylov iteration, or the adjoint of a
partitioned coupling that sweeps once per iteration, pays it once. The move
is then the explicit map ``x = M(u)``, the residual ``x - M(u)`` of a coupled
Newton (:mod:`tofsi.fields.motion`). One increment on the reference mesh is a
linear residual mover, differentiated by :class:`movers.base.Mover` itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from movers.base import MoveReport, element_apply, quality_record
from movers.failure import require_finite_matrices
from movers.problem import MotionProblem
from tofsi.core.kept import input_key
from tofsi.fem.assembly import assemble_vector
from movers.increment_kernel import ElementMatrices, IncrementKernel, schedule, stiffness_points
from movers.increment_solvers import MoveSolver
from tofsi.linalg.superlu import release_free_pages

RAW_SOLVE_TOL = 1e-13
"""A store's triangular solves go unrefined where a factorization's first one left a relative residual below this."""

"""Current corners ``(Em, 4, 2)`` -> unscaled element matrices ``(Em, 8, 8)``; complex-safe."""


def system(bc, Ke: np.ndarray, dofs: np.ndarray, blend):
    """The constrained matrix of ``W K + S_c`` (``K`` itself without a blend)."""
    return bc.matrix(Ke) if blend is None else blend.matrix(bc, Ke, dofs)


@dataclass
class MoveRecord:
    """What a move in increments keeps for its derivatives: each increment's unscaled element
    matrices and constrained system and, by increment, the exact factorization of its system
    where the move made one."""

    matrices: list = field(default_factory=list)
    factors: dict = field(default_factory=dict)
    systems: list = field(default_factory=list)      # each increment's constrained matrix (CSR)


def increment(problem: MotionProblem, element_matrices: ElementMatrices, x: np.ndarray,
              step: np.ndarray, solver, report: MoveReport, guess=None, blend=None,
              record: MoveRecord | None = None, index: int = 0, at: np.ndarray | None = None) -> np.ndarray:
    """The change ``dx`` (2n,) of one increment (number ``index``) from displacement ``x`` (2n,)
    towards ``x + step``, with the stiffness of the mesh at displacement ``at`` (default ``x``);
    ``guess`` starts the iterative solve; ``record`` receives the increment's element matrices
    and factorization. ``solver``: a :class:`~tofsi.linalg.RecyclingSolver` or a
    :class:`MoveSolver`."""
    bc, dofs = problem.bc, problem.dofs
    at = x if at is None else at
    K0, A = stiffness_and_system(problem, element_matrices, at, blend, solver, index, report)
    Ke = K0 * problem.stiffening[:, None, None]
    step_p = np.zeros_like(step)
    step_p[bc.fixed] = step[bc.fixed]
    rhs = -element_apply(Ke, step_p, dofs) if np.any(step_p) else np.zeros_like(step)   # (blended: none)
    if blend is not None:
        rhs = blend.residual(rhs, step, 0.0)      # W (-K_fp d_p) + S_c d
    rhs[bc.fixed] = step[bc.fixed]
    report.linear_solves += 1
    if isinstance(solver, MoveSolver):
        dx, made = solver.solve_increment(index, A, rhs, guess)
    else:
        factorizations = solver.factorizations
        dx = solver.solve(A, rhs, guess)
        made = solver.solver if solver.factorizations > factorizations and solver.solver.exact else None
    dx[bc.fixed] = step[bc.fixed]              # exact, whatever the solver's tolerance
    if record is not None:
        if made is not None:
            record.factors[len(record.matrices)] = made        # made at this system
        record.matrices.append(K0)
        record.systems.append(A)
    return dx


def stiffness_and_system(problem: MotionProblem, element_matrices: ElementMatrices, at: np.ndarray, blend,
                         solver, index: int, report: MoveReport):
    """An increment's unscaled element matrices ``K0`` ``(Em, 8, 8)`` at its stiffness point
    ``at`` (2n,) and its constrained system ``A = W f K0 + S_c`` (:func:`system`). At the
    reference mesh (``at = 0``: every move's first increment) a :class:`MoveSolver`'s bank keeps
    them across the moves at its design, keyed by the kernel's ``key`` (its inputs besides the
    corners: without one, nothing is kept), the corners, the quads, the fixed nodes, the
    stiffening and the blend: a Newton's moves at one design skip a quarter of their element
    matrices and assemblies with the large scene's 4 increments."""
    Xe = problem.points[problem.quads] + at.reshape(-1, 2)[problem.quads]

    def build():
        K0 = element_matrices(Xe)
        require_finite_matrices(problem, K0, index, report)
        return K0, system(problem.bc, K0 * problem.stiffening[:, None, None], problem.dofs, blend)
    key = getattr(element_matrices, "key", None)
    if key is None or not isinstance(solver, MoveSolver) or np.any(at):
        return build()
    blended = () if blend is None else (blend.weight, blend.diag)
    inputs = input_key(key, Xe, problem.dofs, problem.fixed_nodes, problem.stiffening, *blended)
    return solver.bank.reference.get(inputs, build)


def run_increments(problem: MotionProblem, target: np.ndarray, n: int,
                   element_matrices: IncrementKernel, solver, report: MoveReport,
                   progress=None, blend=None, record: MoveRecord | None = None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Apply ``target`` (2n,) in ``n`` increments (their shares of it and stiffness points:
    :func:`schedule`); returns ``x_N`` and ``[x_0, ..., x_N]`` (``record`` receives what the
    derivatives reuse)."""
    x = np.zeros_like(target)
    states = [x]
    fractions, extrapolations = schedule(element_matrices, n)
    dx = None
    for k in range(n):
        a = extrapolations[k]
        at = x + a * dx if a and dx is not None else x
        dx = increment(problem, element_matrices, x, fractions[k] * target, solver, report, guess=dx, blend=blend,
                       record=record, index=k, at=at)
        x = x + dx
        states.append(x)
        report.increments += 1
        quality = quality_record(problem, x.reshape(-1, 2), float(np.sum(fractions[:k + 1])))
        report.quality.append(quality)
        if progress:
            progress(k + 1, n, quality)
    return x, states


class IncrementDerivatives:
    """What the derivatives of one move need of its increments, built once per move: the tangent
    (:func:`increments_jvp`, a Newton's coupling, applied once per Krylov iteration) and the reverse
    sweep (:func:`increments_vjp`, once per adjoint iteration) are linear in their input and share it.

    Per increment ``k`` (``K_k = f K0(y_k)`` at its stiffness point :func:`stiffness_points`,
    ``D_k = d(K0_e(Xe) dx_e)/dXe`` the shape derivative
    of its forces, the kernel's :meth:`~IncrementKernel.force_derivative`): the change ``dx_k``,
    a factorization of its constrained system ``A_k`` (the move's own where it made one, else
    made on first use with ``factorize``, the move's solver kind; it serves ``A_k`` and
    ``A_k^T``), the assembled ``P_f W f D_k``, the element forces ``K0_e dx_e (Em, 8)``, (blended)
    the assembled ``K_k dx_k``, and ``W K_k`` of the quads with a fixed dof (the prescribed
    motion's share). ``record``: what the move kept (its element matrices, systems and
    factorizations; else they are made again); ``keep``: takes the factorizations once made
    (:meth:`movers.increment_solvers.IncrementSolvers.keep`: they precondition the later moves
    at the design). Memory: per increment a factorization of the mesh system and one sparse
    matrix of its pattern. The missing factorizations are made together on first use
    (every sweep needs them all), after the heap's free pages went back to the system
    (:func:`~tofsi.linalg.superlu.release_free_pages`: SuperLU's arrays, sized from a fill
    estimate 5-14 times what they use, would else make memory earlier arrays wrote resident
    again). Nothing here refers back to the move's result: the store goes with it.
    """

    def __init__(self, problem: MotionProblem, states: list[np.ndarray], kernel: IncrementKernel,
                 blend=None, factorize=None, record: MoveRecord | None = None, keep=None):
        bc, dofs, f = problem.bc, problem.dofs, problem.stiffening
        weight = np.ones(2 * problem.n_nodes) if blend is None else blend.weight
        scale = f[:, None, None] * weight[dofs][:, :, None]          # rows of f_e W
        self.edge = np.flatnonzero(bc.is_fixed[dofs].any(axis=1))   # quads with a fixed dof
        self.dofs_edge = dofs[self.edge]
        self.factorize, self.keep = factorize, keep      # keep: takes the factors, for later moves
        self.trusted: dict[tuple[int, bool], bool] = {}    # (increment, transposed) -> raw solves suffice
        self.solvers: list = [None if record is None else record.factors.get(k) for k in range(len(states) - 1)]
        self.increments, self.systems = [], []
        self.fractions, self.extrapolations = schedule(kernel, len(states) - 1)
        for k, y_k in enumerate(stiffness_points(states, self.extrapolations)):
            dx = states[k + 1] - states[k]
            Xe = problem.points[problem.quads] + y_k.reshape(-1, 2)[problem.quads]
            K0 = kernel(Xe) if record is None else record.matrices[k]
            dx_e = dx[dofs]
            WD = bc.row_matrix(scale * kernel.force_derivative(Xe, dx_e)) if k > 0 else None  # x_0 = 0
            forces = np.einsum("eab,eb->ea", K0, dx_e)
            Kdx = None if blend is None else assemble_vector(dofs, f[:, None] * forces, dx.size)
            A = None if self.solvers[k] is not None else (
                system(bc, K0 * f[:, None, None], dofs, blend) if record is None else record.systems[k])
            self.systems.append(A)
            self.increments.append(_Stored(dx, (scale * K0)[self.edge] if self.edge.size else None,
                                           WD, forces, Kdx))

    def _factors(self, k: int):
        if self.systems is not None:            # first use: every sweep needs them all
            if None in self.solvers:
                release_free_pages()
            self.solvers = [self.factorize(A) if s is None else s for s, A in zip(self.solvers, self.systems, strict=True)]
            self.systems = None                 # the factors are what is kept
            if self.keep is not None:
                self.keep(self.solvers)
        return self.solvers[k]

    def _solve(self, k: int, b: np.ndarray, transpose: bool) -> np.ndarray:
        """By the triangular solves alone where the factorization's first solve in this direction
        left a residual below ``RAW_SOLVE_TOL |b|`` (the mesh systems' LU leaves ~1e-15: iterative
        refinement never changes a digit, yet its residual check costs a third of a solve), else
        by the factorization's own (refined) solve."""
        solver = self._factors(k)
        key = (k, transpose)
        trusted = self.trusted.get(key)
        if trusted is None:
            trusted = False
            if solver.exact:                         # a DirectSolver: its matrix A kept
                x = solver.preconditioner(transpose)(b)
                A = solver.A.T if transpose else solver.A
                residual = np.linalg.norm(b - A @ x)
                trusted = bool(np.all(np.isfinite(x))) and residual <= RAW_SOLVE_TOL * np.linalg.norm(b)
            self.trusted[key] = trusted
            if trusted:
                return x
        if trusted:
            return solver.preconditioner(transpose)(b)
        return solver.solve_transpose(b) if transpose else solver.solve(b)

    def solve(self, k: int, b: np.ndarray) -> np.ndarray:
        """``A_k^-1 b`` with increment ``k``'s own factorization (made on first use)."""
        return self._solve(k, b, False)

    def solve_transpose(self, k: int, b: np.ndarray) -> np.ndarray:
        """``A_k^-T b``."""
        return self._solve(k, b, True)

    def edge_apply(self, k: int, v: np.ndarray, size: int, transpose: bool = False) -> np.ndarray:
        """``P_f W K_k v`` (or ``K_k^T W v``) from the quads with a fixed dof only: exact where ``v``
        (``W K_k v``) or the entries read (``K_k^T W v``, at fixed dofs) touch no other quad."""
        WK = self.increments[k].WK_edge
        if WK is None:
            return np.zeros(size)
        return element_apply(WK, v, self.dofs_edge, transpose)


class _Stored(NamedTuple):
    """One increment's share of :class:`IncrementDerivatives`."""

    dx: np.ndarray           # (2n,) its change
    WK_edge: np.ndarray      # (quads with a fixed dof, 8, 8) rows of W f K0
    WD: object               # P_f W f D_k (None for the first increment)
    forces: np.ndarray       # (Em, 8) K0_e dx_e
    Kdx: np.ndarray | None   # (2n,) K_k dx_k (blended)


def derivatives_of(problem: MotionProblem, result, kernel: IncrementKernel) -> IncrementDerivatives:
    """The :class:`IncrementDerivatives` of the move ``result``, built on first use and kept on
    ``result.derivatives``."""
    if result.derivatives is None:
        result.derivatives = IncrementDerivatives(problem, result.trajectory, kernel, result.blend,
                                                  result.solver.factorize, result.record,
                                                  getattr(result.solver, "keep", None))
        result.record = None                    # in the store now (its matrices are not kept twice)
    return result.derivatives


def increments_jvp(problem: MotionProblem, result, kernel: IncrementKernel, t_dot: np.ndarray) -> np.ndarray:
    """Tangent of the move ``result`` (its trajectory, target, solver and blend) along a change
    ``t_dot`` (2n,) of its target, the stiffening and the blend held: ``x_dot`` (2n,). For
    ``k = 0 .. N-1``, from ``x_dot_0 = 0`` and ``d_dot = h_k t_dot`` (:func:`schedule`), each
    increment's own system

        A_k dx_dot = [W (-K_k d_dot_p - f D_k y_dot_k) + S_c d_dot]_f,  dx_dot_p = d_dot_p,
        x_dot_(k+1) = x_dot_k + dx_dot,

    ``y_dot_k = x_dot_k + a_k (x_dot_k - x_dot_(k-1))`` the stiffness point's tangent
    (:func:`schedule`'s ``a_k``)."""
    derivatives = derivatives_of(problem, result, kernel)
    blend, bc = result.blend, problem.bc
    t_dot = np.asarray(t_dot, dtype=float).reshape(-1)
    moved = bool(np.any(t_dot[bc.fixed]))
    x_dot = x_dot_before = np.zeros_like(t_dot)
    for k, inc in enumerate(derivatives.increments):
        step = derivatives.fractions[k] * t_dot     # d_dot of increment k
        a = derivatives.extrapolations[k]
        rhs = np.zeros_like(step) if blend is None else blend.diag * step       # S_c d_dot
        if moved:
            rhs -= derivatives.edge_apply(k, np.where(bc.is_fixed, step, 0.0), step.size)
        if inc.WD is not None:                      # y_dot_k = x_dot_k + a_k (x_dot_k - x_dot_(k-1))
            rhs -= inc.WD @ (x_dot + a * (x_dot - x_dot_before) if a else x_dot)
        rhs[bc.fixed] = step[bc.fixed]
        dx = derivatives.solve(k, rhs)
        dx[bc.fixed] = step[bc.fixed]
        x_dot_before, x_dot = x_dot, x_dot + dx
    return x_dot


def increments_vjp(problem: MotionProblem, result, kernel: IncrementKernel, xbar: np.ndarray):
    """Reverse sweep of the move ``result`` (its trajectory, target, solver and blend):
    ``(target_bar (2n,), stiffening_bar (Em,), blend_bar (n,))``. Its :class:`IncrementDerivatives`
    are built on the first call (of this or :func:`increments_jvp`) and kept for the later ones.
    Per increment, the transposed solve of :func:`movers.base.transposed_solve` with its own
    factorization: ``A_k^T lam_f = xbar_f``, ``lam_p = xbar_p - (K^T W lam_f)_p``."""
    derivatives = derivatives_of(problem, result, kernel)
    blend, bc, dofs = result.blend, problem.bc, problem.dofs
    n = len(derivatives.increments)
    xbar = np.array(xbar, dtype=float).reshape(-1)
    target_bar = np.zeros_like(xbar)
    f_bar = np.zeros(len(problem.quads))
    s_bar = np.zeros(problem.n_nodes)
    carry = 0.0                                     # -a_(k+1) y_bar_(k+1): increment k+1's share of x_k's adjoint
    for k in range(n - 1, -1, -1):
        inc = derivatives.increments[k]
        a, h = derivatives.extrapolations[k], derivatives.fractions[k]
        step_bar = np.zeros_like(xbar)              # increment k's d_bar (d = h_k target)
        lam = derivatives.solve_transpose(k, bc.homogenize(xbar))
        lam[bc.fixed] = 0.0
        step_bar[bc.fixed] = xbar[bc.fixed] - derivatives.edge_apply(k, lam, lam.size, transpose=True)[bc.fixed]
        if blend is not None:                       # the increment's D = W K dx + S_c (dx - d)
            t_blend, s_part = blend.partials(lam, inc.dx, h * result.target, inc.Kdx)
            step_bar -= t_blend
            s_bar -= s_part
        target_bar += h * step_bar
        lam_w = lam if blend is None else blend.weighted(lam)
        f_bar -= np.einsum("ea,ea->e", lam_w[dofs], inc.forces)
        y_bar = None if inc.WD is None else -(inc.WD.T @ lam)    # d/dy_k [(W lam) . f K0(y_k) dx]
        xbar = xbar + carry                         # y_k = (1 + a_k) x_k - a_k x_(k-1)
        carry = 0.0
        if y_bar is not None:
            xbar = xbar + (1 + a) * y_bar if a else xbar + y_bar
            carry = -a * y_bar if a else 0.0
    return target_bar, f_bar, s_bar
