"""Incremental linear mesh motion on the updated mesh, its tangent and its reverse sweep.

Shared by the spring mover and the incremental linear-elastic mover: the
prescribed motion is applied in ``N`` equal increments ``d = u / N``;
increment ``k`` uses the stiffness of the *current* mesh, scaled per quad by
the stiffening factors ``f``, ``K(x_k) = sum_e f_e K0_e(X + x_k)``, and solves

    [[W K_ff + S_c, W K_fp], [0, I]] [dx_f, dx_p] = [S_c d_f, d_p],   x_{k+1} = x_k + dx,

with ``W = 1``, ``S_c = 0`` unless the problem is density-blended
(:mod:`movers.blend`). The pattern (element dofs, Dirichlet mask) is built
once; each increment only recomputes element matrices. Consecutive
increments' matrices differ by O(1/N), so a
:class:`~tofsi.linalg.RecyclingSolver` solves most of them with a few GMRES
iterations preconditioned by an earlier factorization.

Reverse sweep (vector-Jacobian product of ``u, f, s -> x``): with ``xbar`` the
adjoint of ``x_N``, for ``k = N-1 .. 0``

    (W K_ff + S_c)^T lam_f = xbar_f,   lam_p = xbar_p - (K^T W lam_f)_p,
    dbar_f += S_c lam_f,   dbar_p += lam_p,   fbar_e -= (W lam)_e . K0_e dx_e,
    sbar_i -= lam_i . (c_i (dx_i - d_i) - (K dx)_i),
    xbar -= d/dx_k [(W lam_f) . K(x_k) dx]        (shape derivative, complex step),

and ``ubar = dbar / N``. Tangent sweep (Jacobian-vector product of ``u -> x``,
``f`` and ``s`` held): for ``k = 0 .. N-1`` from ``x_dot_0 = 0``, ``d_dot = u_dot / N``,

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

from typing import Callable

import numpy as np

from movers.base import MoveReport, element_apply, quality_record, transposed_solve
from movers.problem import MotionProblem
from tofsi.fem.assembly import assemble_vector
from tofsi.fem.complex_step import corner_derivatives

ElementMatrices = Callable[[np.ndarray], np.ndarray]
"""Current corners ``(Em, 4, 2)`` -> unscaled element matrices ``(Em, 8, 8)``; complex-safe."""


def system(bc, Ke: np.ndarray, dofs: np.ndarray, blend):
    """The constrained matrix of ``W K + S_c`` (``K`` itself without a blend)."""
    return bc.matrix(Ke) if blend is None else blend.matrix(bc, Ke, dofs)


def increment(problem: MotionProblem, element_matrices: ElementMatrices, x: np.ndarray,
              step: np.ndarray, solver, report: MoveReport, guess=None, blend=None) -> np.ndarray:
    """The change ``dx`` (2n,) of one increment from displacement ``x`` (2n,) towards
    ``x + step``; ``guess`` starts the iterative solve."""
    bc, dofs = problem.bc, problem.dofs
    Xe = problem.points[problem.quads] + x.reshape(-1, 2)[problem.quads]
    Ke = element_matrices(Xe) * problem.stiffening[:, None, None]
    step_p = np.zeros_like(step)
    step_p[bc.fixed] = step[bc.fixed]
    rhs = -element_apply(Ke, step_p, dofs)
    if blend is not None:
        rhs = blend.residual(rhs, step, 0.0)      # W (-K_fp d_p) + S_c d
    rhs[bc.fixed] = step[bc.fixed]
    report.linear_solves += 1
    dx = solver.solve(system(bc, Ke, dofs, blend), rhs, guess)
    dx[bc.fixed] = step[bc.fixed]              # exact, whatever the solver's tolerance
    return dx


def run_increments(problem: MotionProblem, target: np.ndarray, n: int,
                   element_matrices: ElementMatrices, solver, report: MoveReport,
                   progress=None, blend=None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Apply ``target`` (2n,) in ``n`` increments; returns ``x_N`` and ``[x_0, ..., x_N]``."""
    x = np.zeros_like(target)
    states = [x]
    step = target / n
    dx = None
    for k in range(n):
        dx = increment(problem, element_matrices, x, step, solver, report, guess=dx, blend=blend)
        x = x + dx
        states.append(x)
        report.increments += 1
        record = quality_record(problem, x.reshape(-1, 2), (k + 1) / n)
        report.quality.append(record)
        if progress:
            progress(k + 1, n, record)
    return x, states


class IncrementDerivatives:
    """What the derivatives of one move need of its increments, built once per move: the tangent
    (:func:`increments_jvp`, a Newton's coupling, applied once per Krylov iteration) and the reverse
    sweep (:func:`increments_vjp`, once per adjoint iteration) are linear in their input and share it.

    Per increment ``k``: the unstiffened element matrices ``K0_k (Em, 8, 8)`` of the mesh ``x_k``,
    the change ``dx_k``, the constrained system matrix ``A_k`` of its solve, the element Jacobian
    ``D_k = d(K0_e(Xe) dx_e)/dXe (Em, 8, 8)`` of its forces with respect to the corners (the
    kernel's :meth:`~IncrementKernel.force_derivative`) and, on first use, a factorization of
    ``A_k`` (``factorize``, the move's solver kind) that serves ``A_k`` and ``A_k^T``. Memory: per
    increment a factorization of the mesh system and two ``(Em, 8, 8)`` arrays (about 3 MB at
    80 x 40).
    """

    def __init__(self, problem: MotionProblem, states: list[np.ndarray], kernel: "IncrementKernel",
                 blend=None, factorize=None):
        dofs, f = problem.dofs, problem.stiffening
        self.factorize = factorize
        self.increments = []
        for k in range(len(states) - 1):
            x_k, dx = states[k], states[k + 1] - states[k]
            Xe = problem.points[problem.quads] + x_k.reshape(-1, 2)[problem.quads]
            K0 = kernel(Xe)
            D = kernel.force_derivative(Xe, dx[dofs]) if k > 0 else None   # x_0 = 0 depends on nothing
            A = system(problem.bc, K0 * f[:, None, None], dofs, blend)
            self.increments.append((K0, dx, D, A))
        self.solvers: list = [None] * len(self.increments)

    def _factors(self, k: int):
        if self.solvers[k] is None:
            self.solvers[k] = self.factorize(self.increments[k][3])
        return self.solvers[k]

    def solve(self, k: int, b: np.ndarray) -> np.ndarray:
        """``A_k^-1 b`` with increment ``k``'s own factorization (made on first use)."""
        return self._factors(k).solve(b)

    def solve_transpose(self, k: int, A, b: np.ndarray) -> np.ndarray:
        """``A_k^-T b`` (``A``: ``A_k``, as a recycling solver is called)."""
        return self._factors(k).solve_transpose(b)


class IncrementKernel:
    """A mover's element matrices of the current mesh, ``Xe (Em, 4, 2) -> K0 (Em, 8, 8)``
    (unscaled, complex-safe), and the shape derivative of their forces
    ``d(K0(Xe) v_e)/dXe (Em, 8, 8)``: ``force_derivative`` where the mover gives it in closed
    form, else by complex step (eight evaluations of the matrices)."""

    def __init__(self, matrices: ElementMatrices, force_derivative=None):
        self.matrices, self.closed_form = matrices, force_derivative

    def __call__(self, Xe: np.ndarray) -> np.ndarray:
        return self.matrices(Xe)

    def force_derivative(self, Xe: np.ndarray, v: np.ndarray) -> np.ndarray:
        if self.closed_form is not None:
            return self.closed_form(Xe, v)
        return corner_derivatives(lambda Xc: np.einsum("eab,eb->ea", self.matrices(Xc), v), Xe)


class _Increment:
    """One increment's factorization in the interface of a recycling solver (``solve_transpose(A, b)``)."""

    def __init__(self, derivatives: IncrementDerivatives, k: int):
        self.derivatives, self.k = derivatives, k

    def solve_transpose(self, A, b):
        return self.derivatives.solve_transpose(self.k, A, b)


def derivatives_of(problem: MotionProblem, result, kernel: IncrementKernel) -> IncrementDerivatives:
    """The :class:`IncrementDerivatives` of the move ``result``, built on first use and kept on
    ``result.derivatives``."""
    if result.derivatives is None:
        result.derivatives = IncrementDerivatives(problem, result.trajectory, kernel, result.blend,
                                                  result.solver.factorize)
    return result.derivatives


def increments_jvp(problem: MotionProblem, result, kernel: IncrementKernel, t_dot: np.ndarray) -> np.ndarray:
    """Tangent of the move ``result`` (its trajectory, target, solver and blend) along a change
    ``t_dot`` (2n,) of its target, the stiffening and the blend held: ``x_dot`` (2n,). For
    ``k = 0 .. N-1``, from ``x_dot_0 = 0`` and ``d_dot = t_dot / N``, each increment's own system

        A_k dx_dot = [W (-K_k d_dot_p - f D_k x_dot_k) + S_c d_dot]_f,  dx_dot_p = d_dot_p,
        x_dot_(k+1) = x_dot_k + dx_dot."""
    derivatives = derivatives_of(problem, result, kernel)
    blend, bc = result.blend, problem.bc
    dofs, f = problem.dofs, problem.stiffening
    n = len(derivatives.increments)
    step = np.asarray(t_dot, dtype=float).reshape(-1) / n
    step_p = np.where(bc.is_fixed, step, 0.0)
    x_dot = np.zeros_like(step)
    for k in range(n):
        K0, _, D, _ = derivatives.increments[k]
        forces = np.einsum("eab,eb->ea", K0, step_p[dofs])
        if D is not None:
            forces += np.einsum("eaj,ej->ea", D, x_dot[dofs])
        rhs = -assemble_vector(dofs, f[:, None] * forces, step.size)
        if blend is not None:
            rhs = blend.residual(rhs, step, 0.0)       # W rhs + S_c d_dot
        rhs[bc.fixed] = step[bc.fixed]
        dx = derivatives.solve(k, rhs)
        dx[bc.fixed] = step[bc.fixed]
        x_dot = x_dot + dx
    return x_dot


def increments_vjp(problem: MotionProblem, result, kernel: IncrementKernel, xbar: np.ndarray):
    """Reverse sweep of the move ``result`` (its trajectory, target, solver and blend):
    ``(target_bar (2n,), stiffening_bar (Em,), blend_bar (n,))``. Its :class:`IncrementDerivatives`
    are built on the first call (of this or :func:`increments_jvp`) and kept for the later ones."""
    derivatives = derivatives_of(problem, result, kernel)
    blend = result.blend
    dofs, f = problem.dofs, problem.stiffening
    n = len(derivatives.increments)
    step = result.target / n
    xbar = np.array(xbar, dtype=float).reshape(-1)
    step_bar = np.zeros_like(xbar)
    f_bar = np.zeros(len(problem.quads))
    s_bar = np.zeros(problem.n_nodes)
    for k in range(n - 1, -1, -1):
        K0, dx, D, A = derivatives.increments[k]
        Ke = K0 * f[:, None, None]
        lam, lam_p = transposed_solve(problem, Ke, xbar, _Increment(derivatives, k), blend, A)
        step_bar += lam_p
        lam_w = lam if blend is None else blend.weighted(lam)
        if blend is not None:                       # the increment's D = W K dx + S_c (dx - d)
            t_blend, s_part = blend.partials(lam, dx, step, element_apply(Ke, dx, dofs))
            step_bar -= t_blend
            s_bar -= s_part
        lam_e, dx_e = lam_w[dofs], dx[dofs]
        f_bar -= np.einsum("ea,eab,eb->e", lam_e, K0, dx_e)
        if D is not None:                           # d/dx_k [(W lam) . f K0(x_k) dx]
            xbar = xbar - assemble_vector(dofs, f[:, None] * np.einsum("eaj,ea->ej", D, lam_e), xbar.size)
    return step_bar / n, f_bar, s_bar
