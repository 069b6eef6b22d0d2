"""Incremental linear mesh motion on the updated mesh.

Shared by the spring mover and the incremental linear-elastic mover: the
prescribed motion is applied in ``N`` equal increments; increment ``k``
solves the stiffness of the *current* mesh ``K(X + x_k)``:

    K_ff(X + x_k) dx_f = -K_fp(X + x_k) du_p,   dx_p = du_p = u_p / N,
    x_{k+1} = x_k + dx.

The pattern (element dofs, Dirichlet mask) is built once; each increment
only recomputes element matrices and factorizes.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from movers.base import MotionProblem, MoveReport, quality_record
from tofsi.fem.assembly import assemble_vector

ElementMatrices = Callable[[np.ndarray], np.ndarray]     # current corners (Em, 4, 2) -> (Em, 8, 8)


def increment(problem: MotionProblem, bc, element_matrices: ElementMatrices, x: np.ndarray,
              step: np.ndarray, make_solver, report: MoveReport) -> np.ndarray:
    """One increment from displacement ``x`` (2n,) by the prescribed ``step`` (2n, zero on free)."""
    dofs = problem.dofs
    Xe = problem.points[problem.quads] + x.reshape(-1, 2)[problem.quads]
    Ke = element_matrices(Xe)
    rhs = -assemble_vector(dofs, np.einsum("eab,eb->ea", Ke, step[dofs]), step.size)
    rhs[bc.fixed] = step[bc.fixed]
    solver = make_solver(bc.matrix(Ke))
    report.linear_solves += 1
    return x + solver.solve(rhs)


def run_increments(problem: MotionProblem, target: np.ndarray, n: int,
                   element_matrices: ElementMatrices, make_solver, report: MoveReport,
                   progress=None, x0: np.ndarray | None = None) -> np.ndarray:
    """Apply ``target`` (2n,) in ``n`` increments; returns the displacement (2n,)."""
    bc = problem.dirichlet()
    x = np.zeros_like(target) if x0 is None else x0.copy()
    step = target / n
    for k in range(n):
        x = increment(problem, bc, element_matrices, x, step, make_solver, report)
        report.increments += 1
        record = quality_record(problem, x.reshape(-1, 2), (k + 1) / n)
        report.quality.append(record)
        if progress:
            progress(k + 1, n, record)
    return x
