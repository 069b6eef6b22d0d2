"""The flow's nonlinear solve: steady Navier-Stokes by Newton's method, and its report.

Newton with inexact (Eisenstat-Walker) linear solves and a backtracking line
search on ``|R|``; converged when ``|F|`` is below ``fluid.newton_tol`` times
the force scale of :meth:`~tofsi.physics.flow.Flow.residual_scale`, or when the
componentwise backward error ``max_i |r_i| / (|J| |w|)_i`` has reached
round-off. When it fails at the full Reynolds number, continuation in the
fluid density from Stokes flow (``fluid.continuation_steps`` steps). Every
solve reports its history and raises :class:`~tofsi.core.errors.NumericalError`
rather than return an unconverged state.

The flow (:class:`~tofsi.physics.flow.Flow`) gives the residual, the Jacobian,
the force scale and the factorizer of its Jacobians; this module holds the
iteration alone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.sparse as sp

from tofsi.core.errors import NumericalError
from tofsi.core.iteration import backtracking, forcing_term
from tofsi.linalg import RecyclingSolver
from tofsi.linalg.block_matrix import absolute_product

log = logging.getLogger(__name__)
ROUND_OFF = 64 * np.finfo(float).eps        # componentwise backward error that counts as exact


@dataclass
class FlowReport:
    converged: bool = False
    newton_iterations: int = 0
    residual_history: list = field(default_factory=list)
    continuation: list = field(default_factory=list)      # densities used when continuing
    wall_time_s: float = 0.0

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class FlowSolution:
    """A converged flow with the Jacobian of its last Newton check and the solver that
    holds the last factorization (the adjoint solves with both)."""

    w: np.ndarray
    report: FlowReport
    jacobian: sp.csr_matrix
    solver: RecyclingSolver


def newton_solve(flow, x=None, rho=None, w0=None, params=None,
                 solver: RecyclingSolver | None = None, tol: float | None = None) -> FlowSolution:
    """Steady flow of ``flow`` on the mesh moved by ``x`` with densities ``rho``, from ``w0``
    (its fixed values replaced by the boundary values; default: :meth:`Flow.initial
    <tofsi.physics.flow.Flow.initial>`), with the converged Jacobian and the solver
    (``solver``: one whose last factorization may precondition this solve's Newton steps; a
    new one by default; ``tol``: the tolerance relative to the force scale instead of
    ``fluid.newton_tol``, for a solve that only starts a coupled Newton); raises on failure."""
    t0 = time.perf_counter()
    report = FlowReport()
    factorize = flow.factorizer(x, rho, params)     # a previous design's factors start; new ones are this design's
    solver = RecyclingSolver(factorize) if solver is None else solver.with_factorize(factorize)
    w = flow.initial(params) if w0 is None else np.where(flow.bc.is_fixed, flow.boundary_values(params), w0)
    try:
        w, J = newton(flow, w, x, rho, flow.density, report, params, solver, tol)
    except NumericalError as first:
        if flow.density == 0.0:
            raise
        log.info("Newton failed at full Reynolds number (%s); continuing from Stokes flow", first)
        w, J = newton(flow, flow.initial(params), x, rho, 0.0, report, params, solver, tol)
        steps = flow.settings.continuation_steps
        for k in range(1, steps + 1):
            density = flow.density * k / steps
            report.continuation.append(density)
            w, J = newton(flow, w, x, rho, density, report, params, solver, tol)
    report.converged = True
    report.wall_time_s = time.perf_counter() - t0
    return FlowSolution(w, report, J, solver)


def backward_error(J, w, r) -> float:
    """Componentwise relative residual ``max_i |r_i| / (|J| |w|)_i``: round-off level
    (~1e-16) means no more digits can be had, whatever the rows' scales (Brinkman rows
    with alpha = 1e9 next to viscous rows of order 1)."""
    size = absolute_product(J, np.abs(w))
    floor = 1e-300 + 1e-16 * size.max()
    return float(np.max(np.abs(r) / (size + floor)))


def newton(flow, w, x, rho, density, report: FlowReport, params, solver, tol: float | None = None):
    """Newton with inexact (Eisenstat-Walker) solves and a backtracking line search whose
    accepted full step's Jacobian is the next iteration's, at fluid density ``density``.
    Converged when ``|F|`` is below ``newton_tol`` times the force scale, or when the
    componentwise backward error has reached round-off (``ROUND_OFF``); ``tol`` replaces
    ``newton_tol``. Returns ``w`` and the Jacobian at ``w``."""
    s, bc = flow.settings, flow.bc
    target = (s.newton_tol if tol is None else tol) * flow.residual_scale(x, density)
    history: list[float] = []
    report.residual_history.append(history)
    J, R = flow.jacobian(w, x, rho, density, params)
    for it in range(s.newton_max_iter + 1):
        r = bc.homogenize(R)
        norm = float(np.linalg.norm(r))
        history.append(norm)
        log.info("flow Newton %d (density %.4g): |R| = %.3e, target %.3e", it, density, norm, target)
        if not np.isfinite(norm):
            raise NumericalError("flow solve: non-finite residual", {"history": history})
        if norm <= target or backward_error(J, w, r) <= ROUND_OFF:
            return w, J
        if it == s.newton_max_iter:
            break
        dw = solver.solve(J, -r, rtol=forcing_term(history, target))
        dw[bc.fixed] = 0.0
        report.newton_iterations += 1
        J = None                          # let this Jacobian go before the trial's is assembled

        def trial(alpha, w=w, dw=dw):
            w_t = w + alpha * dw
            if alpha == 1.0:                        # keep the Jacobian: next iteration's
                J_t, R_t = flow.jacobian(w_t, x, rho, density, params)
            else:
                J_t, R_t = None, flow.residual(w_t, x, rho, density, params)
            return float(np.linalg.norm(bc.homogenize(R_t))), (w_t, J_t, R_t)
        found = backtracking(norm, trial)
        if found is None:
            raise NumericalError("flow solve: line search found no decrease",
                                 {"history": history, "density": density})
        w, J, R = found[1]
        del found                         # (it holds this Jacobian: let it go with J)
        if J is None:
            J, R = flow.jacobian(w, x, rho, density, params)
    raise NumericalError(f"flow solve: no convergence in {s.newton_max_iter} Newton iterations",
                         {"history": history, "density": density})
