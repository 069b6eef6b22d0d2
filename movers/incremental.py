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

and ``ubar = dbar / N``. One increment on the reference mesh is the
implicit-function adjoint of a residual mover: :func:`transposed_solve`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

from movers.base import MotionProblem, MoveReport, quality_record
from tofsi.fem.assembly import assemble_vector

ElementMatrices = Callable[[np.ndarray], np.ndarray]
"""Current corners ``(Em, 4, 2)`` -> unscaled element matrices ``(Em, 8, 8)``; complex-safe."""

COMPLEX_STEP = 1e-30


def element_apply(Ke: np.ndarray, v: np.ndarray, dofs: np.ndarray, transpose: bool = False) -> np.ndarray:
    """Global ``K v`` (or ``K^T v``) from element matrices, without assembling ``K``."""
    spec = "eba,eb->ea" if transpose else "eab,eb->ea"
    return assemble_vector(dofs, np.einsum(spec, Ke, v[dofs]), v.size)


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
        rhs = blend.weighted(rhs) + blend.diag * step
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


def transposed_solve(bc, A, Ke: np.ndarray, dofs: np.ndarray, rhs: np.ndarray, solver, blend=None):
    """Adjoint of ``[[W K_ff + S_c, W K_fp], [0, I]]`` (matrix ``A``, element matrices ``Ke`` of ``K``).

    Returns ``lam`` (zero on fixed dofs) and ``lam_p`` (zero on free dofs):
    ``A_ff^T lam_f = rhs_f``, ``lam_p = rhs_p - (K^T W lam_f)_p``. Uses the same
    Dirichlet operator as the forward solve, with homogeneous values.
    """
    lam = solver.solve_transpose(A, bc.homogenize(rhs))
    lam[bc.fixed] = 0.0
    lam_w = lam if blend is None else blend.weighted(lam)
    lam_p = np.zeros_like(rhs)
    lam_p[bc.fixed] = rhs[bc.fixed] - element_apply(Ke, lam_w, dofs, transpose=True)[bc.fixed]
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


def increments_vjp(problem: MotionProblem, states: list[np.ndarray], target: np.ndarray,
                   element_matrices: ElementMatrices, solver, xbar: np.ndarray, blend=None):
    """Reverse sweep: ``(target_bar (2n,), stiffening_bar (Em,), blend_bar (n,))``."""
    bc, dofs, f = problem.bc, problem.dofs, problem.stiffening
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
        lam, lam_p = transposed_solve(bc, system(bc, Ke, dofs, blend), Ke, dofs, xbar, solver, blend)
        step_bar += lam_p
        lam_w = lam if blend is None else blend.weighted(lam)
        if blend is not None:
            step_bar += blend.diag * lam
            Kdx = element_apply(Ke, dx, dofs)
            s_bar -= (lam * (np.repeat(blend.c, 2) * (dx - step) - Kdx)).reshape(-1, 2).sum(axis=1)
        lam_e, dx_e = lam_w[dofs], dx[dofs]
        f_bar -= np.einsum("ea,eab,eb->e", lam_e, K0, dx_e)
        if k > 0:                                   # x_0 = 0 does not depend on anything
            xbar = xbar - assemble_vector(dofs, shape_vjp(element_matrices, Xe, f, lam_e, dx_e), xbar.size)
    return step_bar / n, f_bar, s_bar


def linear_residual(problem: MotionProblem, Ke: np.ndarray, x: np.ndarray, target: np.ndarray, blend):
    """``D(x)`` and true ``D_x`` of the one-increment (linear) mover ``K x = 0``."""
    bc, dofs = problem.bc, problem.dofs
    r = element_apply(Ke, x, dofs)
    if blend is not None:
        r = blend.weighted(r) + blend.diag * (x - target)
    r = bc.homogenize(r)
    r[bc.fixed] = (x - target)[bc.fixed]
    K = bc.row_matrix(Ke if blend is None else Ke * blend.weight[dofs][:, :, None])
    if blend is not None:
        K = K + sp.diags(blend.diag)
    return r, K.tocsr()


def linear_partials(problem: MotionProblem, K0: np.ndarray, x, target, lam, blend):
    """``lam^T dD/d(target, f, s)`` of ``D = W K x + S_c (x - target)``, fixed rows ``x - target``."""
    bc, dofs = problem.bc, problem.dofs
    lam_f = bc.homogenize(lam)
    t_bar = np.zeros_like(lam)
    t_bar[bc.fixed] = -lam[bc.fixed]
    lam_w = lam_f if blend is None else blend.weighted(lam_f)
    f_bar = np.einsum("ea,eab,eb->e", lam_w[dofs], K0, x[dofs])
    s_bar = np.zeros(problem.n_nodes)
    if blend is not None:
        t_bar -= blend.diag * lam_f
        Kx = element_apply(K0 * problem.stiffening[:, None, None], x, dofs)
        s_bar = (lam_f * (np.repeat(blend.c, 2) * (x - target) - Kx)).reshape(-1, 2).sum(axis=1)
    return t_bar, f_bar, s_bar
