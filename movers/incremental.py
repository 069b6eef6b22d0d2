"""Incremental linear mesh motion on the updated mesh, and its reverse sweep.

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

and ``ubar = dbar / N``. One increment on the reference mesh is a linear
residual mover, differentiated by :class:`movers.base.Mover` itself.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from movers.base import MotionProblem, MoveReport, element_apply, quality_record, transposed_solve
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


def shape_vjp(element_matrices: ElementMatrices, Xe: np.ndarray, factors: np.ndarray,
              lam_e: np.ndarray, v_e: np.ndarray) -> np.ndarray:
    """``d/dXe [lam_e . f_e K0_e(Xe) v_e]`` ``(Em, 8)`` by the complex step (exact to round-off)."""
    return factors[:, None] * corner_derivatives(
        lambda Xc: np.einsum("ea,eab,eb->e", lam_e, element_matrices(Xc), v_e), Xe)


def increments_vjp(problem: MotionProblem, states: list[np.ndarray], target: np.ndarray,
                   element_matrices: ElementMatrices, solver, xbar: np.ndarray, blend=None):
    """Reverse sweep: ``(target_bar (2n,), stiffening_bar (Em,), blend_bar (n,))``."""
    dofs, f = problem.dofs, problem.stiffening
    n = len(states) - 1
    step = target / n
    xbar = np.array(xbar, dtype=float).reshape(-1)
    step_bar = np.zeros_like(xbar)
    f_bar = np.zeros(len(problem.quads))
    s_bar = np.zeros(problem.n_nodes)
    for k in range(n - 1, -1, -1):
        x_k, dx = states[k], states[k + 1] - states[k]
        Xe = problem.points[problem.quads] + x_k.reshape(-1, 2)[problem.quads]
        K0 = element_matrices(Xe)
        Ke = K0 * f[:, None, None]
        lam, lam_p = transposed_solve(problem, Ke, xbar, solver, blend)
        step_bar += lam_p
        lam_w = lam if blend is None else blend.weighted(lam)
        if blend is not None:                       # the increment's D = W K dx + S_c (dx - d)
            t_blend, s_part = blend.partials(lam, dx, step, element_apply(Ke, dx, dofs))
            step_bar -= t_blend
            s_bar -= s_part
        lam_e, dx_e = lam_w[dofs], dx[dofs]
        f_bar -= np.einsum("ea,eab,eb->e", lam_e, K0, dx_e)
        if k > 0:                                   # x_0 = 0 does not depend on anything
            xbar = xbar - assemble_vector(dofs, shape_vjp(element_matrices, Xe, f, lam_e, dx_e), xbar.size)
    return step_bar / n, f_bar, s_bar
