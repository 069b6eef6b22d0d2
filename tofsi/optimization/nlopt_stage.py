"""One continuation stage run by NLopt (MMA or CCSAQ): the algorithms, the early stop, the run.

Both optimizers -- the serial :class:`tofsi.optimization.optimize.Optimizer` and the
distributed :mod:`tofsi.parallel.optimize_flow` -- minimize the stage's
scaled objective ``f / f(stage start)`` over ``0 <= gamma <= 1`` under
``g(gamma) <= 0`` with the same NLopt set-up, stop a stage early by the same
rule (:func:`settled`) and name NLopt's end the same way (:func:`stop_reason`).
"""

from __future__ import annotations

from itertools import pairwise

import nlopt
import numpy as np

ALGORITHMS = {"MMA": nlopt.LD_MMA, "CCSAQ": nlopt.LD_CCSAQ}
MIN_STAGE = 5            # evaluations before a stage may stop on small changes
INITIAL_STEP = 0.05      # MMA's initial asymptote distance (a move limit for the first steps)


def stop_reason(result: int) -> str:
    """Why NLopt ended a stage: ``max_iter`` (the evaluation budget) or NLopt's own reason."""
    if result == nlopt.MAXEVAL_REACHED:
        return "max_iter"
    names = {v: k.lower() for k, v in vars(nlopt).items() if k.isupper() and k.endswith(("REACHED", "LIMITED"))}
    return f"nlopt {names.get(result, result)}"


def settled(rows, settings) -> bool:
    """A stage's rows (``Iteration`` records, its first first) have settled: after ``MIN_STAGE``
    evaluations, the largest change below ``tol_change`` twice in a row, or the relative
    objective change below ``tol_objective`` ``stall_iterations`` times in a row (topFlow's
    rule with 5 and 1e-3)."""
    s = settings
    if len(rows) < max(MIN_STAGE, s.stall_iterations + 1):
        return False
    if all(it.change < s.tol_change for it in rows[-2:]):
        return True
    f = [it.objective for it in rows[-(s.stall_iterations + 1):]]
    return all(abs(b - a) <= s.tol_objective * max(abs(a), 1e-300) for a, b in pairwise(f))


def run_stage(algorithm: str, start: np.ndarray, step: float, objective, constraint, n_constraints: int,
              max_evaluations: int) -> tuple[np.ndarray | None, str]:
    """NLopt's ``algorithm`` from ``start`` (clipped to [0, 1]) with initial step ``step`` for at most
    ``max_evaluations`` evaluations; ``objective(x, grad)`` and ``constraint(result, x, grad)`` in
    NLopt's form (the objective raises ``nlopt.ForcedStop`` once the stage has settled).
    Returns ``(the design, stop reason)``, or ``(None, "converged")`` after a forced stop (the
    caller keeps the last evaluated design)."""
    opt = nlopt.opt(ALGORITHMS[algorithm], start.size)
    opt.set_lower_bounds(np.zeros(start.size))
    opt.set_upper_bounds(np.ones(start.size))
    opt.set_initial_step(np.full(start.size, step))
    opt.set_min_objective(objective)
    opt.add_inequality_mconstraint(constraint, [1e-8] * n_constraints)
    opt.set_maxeval(max_evaluations)
    try:
        gamma = np.asarray(opt.optimize(np.clip(start, 0.0, 1.0)))
    except nlopt.ForcedStop:
        return None, "converged"
    return gamma, stop_reason(opt.last_optimize_result())
