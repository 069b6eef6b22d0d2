"""Incremental linear mesh motion on the updated mesh, and its reverse sweep.

Shared by the spring mover and the incremental linear-elastic mover: the
prescribed motion is applied in ``N`` equal increments ``d = u_p / N``;
increment ``k`` solves the stiffness of the *current* mesh, scaled per quad
by the stiffening factors ``f``, ``K(x_k) = sum_e f_e K0_e(X + x_k)``:

    [[K_ff, K_fp], [0, I]] [dx_f, dx_p] = [0, d],    x_{k+1} = x_k + dx.

The pattern (element dofs, Dirichlet mask) is built once; each increment
only recomputes element matrices. Consecutive increments' matrices differ
by O(1/N), so a :class:`~tofsi.linalg.RecyclingSolver` solves most of them
with a few GMRES iterations preconditioned by an earlier factorization.

Reverse sweep (vector-Jacobian product of ``u_p, f -> x``): with ``xbar`` the
adjoint of ``x_N``, for ``k = N-1 .. 0``

    K_ff^T lam_f = xbar_f,   lam_p = xbar_p - K_fp^T lam_f,
    dbar += lam_p,   fbar_e -= lam_e . K0_e dx_e,
    xbar -= d/dx_k [lam_f . K(x_k) dx]     (shape derivative, complex step),

and ``u_pbar = dbar / N``. A single increment on the reference mesh is the
implicit-function-theorem adjoint of a residual mover, ``transposed_solve``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from movers.base import MotionProblem, MoveReport, quality_record
from tofsi.fem.assembly import assemble_vector

ElementMatrices = Callable[[np.ndarray], np.ndarray]
"""Current corners ``(Em, 4, 2)`` -> unscaled element matrices ``(Em, 8, 8)``; complex-safe."""

COMPLEX_STEP = 1e-30


def _element_apply(Ke: np.ndarray, v: np.ndarray, dofs: np.ndarray) -> np.ndarray:
    """Global ``K v`` from element matrices, without assembling ``K``."""
    return assemble_vector(dofs, np.einsum("eab,eb->ea", Ke, v[dofs]), v.size)


def increment(problem: MotionProblem, bc, element_matrices: ElementMatrices, x: np.ndarray,
              step: np.ndarray, solver, report: MoveReport, guess=None) -> np.ndarray:
    """The change ``dx`` (2n,) of one increment from displacement ``x`` (2n,) by the
    prescribed ``step`` (2n, zero on free dofs); ``guess`` starts the iterative solve."""
    dofs = problem.dofs
    Xe = problem.points[problem.quads] + x.reshape(-1, 2)[problem.quads]
    Ke = element_matrices(Xe) * problem.stiffening[:, None, None]
    rhs = -_element_apply(Ke, step, dofs)
    rhs[bc.fixed] = step[bc.fixed]
    report.linear_solves += 1
    dx = solver.solve(bc.matrix(Ke), rhs, guess)
    dx[bc.fixed] = step[bc.fixed]              # exact, whatever the solver's tolerance
    return dx


def run_increments(problem: MotionProblem, target: np.ndarray, n: int,
                   element_matrices: ElementMatrices, solver, report: MoveReport,
                   progress=None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Apply ``target`` (2n,) in ``n`` increments; returns ``x_N`` and ``[x_0, ..., x_N]``."""
    bc = problem.dirichlet()
    x = np.zeros_like(target)
    states = [x]
    step = target / n
    dx = None
    for k in range(n):
        dx = increment(problem, bc, element_matrices, x, step, solver, report, guess=dx)
        x = x + dx
        states.append(x)
        report.increments += 1
        record = quality_record(problem, x.reshape(-1, 2), (k + 1) / n)
        report.quality.append(record)
        if progress:
            progress(k + 1, n, record)
    return x, states


def transposed_solve(bc, Ke: np.ndarray, dofs: np.ndarray, rhs: np.ndarray, solver):
    """Adjoint of ``[[K_ff, K_fp], [0, I]]``: returns ``lam_f`` (zero on fixed dofs) and ``lam_p``.

    ``K_ff^T lam_f = rhs_f``, ``lam_p = rhs_p - (K^T lam_f)_p``; ``Ke`` are the
    (scaled) element matrices of ``K``. Uses the same Dirichlet operator as
    the forward solve, with homogeneous values.
    """
    lam = solver.solve_transpose(bc.matrix(Ke), bc.homogenize(rhs))
    lam[bc.fixed] = 0.0
    lam_p = np.zeros_like(rhs)
    KTlam = assemble_vector(dofs, np.einsum("eba,eb->ea", Ke, lam[dofs]), rhs.size)
    lam_p[bc.fixed] = rhs[bc.fixed] - KTlam[bc.fixed]
    return lam, lam_p


def shape_vjp(element_matrices: ElementMatrices, Xe: np.ndarray, factors: np.ndarray,
              lam_e: np.ndarray, v_e: np.ndarray) -> np.ndarray:
    """``d/dXe [lam_e . f_e K0_e(Xe) v_e]`` ``(Em, 8)`` by the complex step (exact to round-off)."""
    out = np.empty(lam_e.shape)
    for j in range(8):
        Xc = Xe.astype(complex)
        Xc[:, j // 2, j % 2] += 1j * COMPLEX_STEP
        dK = element_matrices(Xc).imag / COMPLEX_STEP
        out[:, j] = factors * np.einsum("ea,eab,eb->e", lam_e, dK, v_e)
    return out


def increments_vjp(problem: MotionProblem, states: list[np.ndarray],
                   element_matrices: ElementMatrices, solver, xbar: np.ndarray):
    """Reverse sweep: ``(target_bar (2n,), stiffening_bar (Em,))`` for ``xbar`` on ``x_N``."""
    bc = problem.dirichlet()
    dofs, f = problem.dofs, problem.stiffening
    n = len(states) - 1
    xbar = np.array(xbar, dtype=float).reshape(-1)
    step_bar = np.zeros_like(xbar)
    f_bar = np.zeros(len(problem.quads))
    for k in range(n - 1, -1, -1):
        x_k, dx = states[k], states[k + 1] - states[k]
        Xe = problem.points[problem.quads] + x_k.reshape(-1, 2)[problem.quads]
        K0 = element_matrices(Xe)
        lam, lam_p = transposed_solve(bc, K0 * f[:, None, None], dofs, xbar, solver)
        step_bar += lam_p
        lam_e, dx_e = lam[dofs], dx[dofs]
        f_bar -= np.einsum("ea,eab,eb->e", lam_e, K0, dx_e)
        if k > 0:                                   # x_0 = 0 does not depend on anything
            xbar = xbar - assemble_vector(dofs, shape_vjp(element_matrices, Xe, f, lam_e, dx_e), xbar.size)
    return step_bar / n, f_bar
