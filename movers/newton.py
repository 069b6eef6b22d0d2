"""Newton with load steps, cutbacks and a secant line search: the Yeoh mover's, on any operators.

The equations ``D(x) = 0`` at load ``lambda`` -- free rows ``W R(x) + S_c (x - lambda t)``, fixed
rows ``x_p = lambda t_p`` (``W = 1``, ``S_c = 0`` without a density blend) -- are solved by
:class:`LoadStepNewton` through an operator object (:class:`NewtonOperators`): the serial Yeoh
mover's (:class:`movers.yeoh.SerialOperators`: the whole mesh's kernel, a
:class:`~tofsi.linalg.RecyclingSolver`) and the mover by slabs'
(:class:`tofsi.parallel.slab_mover.SlabOperators`: kernels on each rank's slab, sums over ranks,
MUMPS factors across the ranks, validity on every rank) run the same algorithm:

* a move given a nearby displacement (the previous sweep's or design's) makes one Newton solve
  from there straight to the full motion when its prescribed values are nearer the target than
  zero is; when that fails, and without one, the motion is applied in load steps
  ``lambda = 0 -> 1`` (``increments`` at first; an easy step, at most 4 residuals, lengthens the
  next by 1.5);
* each step starts with the tangent predictor (the fixed dofs' step ``d_p`` and the free dofs'
  linear response ``-A_ff^-1 (D + W K_fp d_p)``, solved to 1e-3), then Newton corrections
  ``A dx = -D`` solved to Eisenstat-Walker's forcing term, with the line search on the energy's
  slope ``g(alpha) = dx . D(x + alpha dx)`` (:meth:`LoadStepNewton.line_search`); every trial must
  be valid (no element inverted) and reduce ``|D|``;
* converged when ``|D_free| <= max(newton_tol max(scale, |R|), 1e3 eps sqrt(2n) |R|)``, ``scale``
  the step's initial residual, boundary response and reactions (:meth:`LoadStepNewton.tolerance`);
* a failed step is cut in half; below ``min_increment``, past ``max_cutbacks`` cuts, or when one
  element has blocked ``BLOCKED_CUTBACKS`` cut steps (inverted by their trials: the mesh folds
  there, each cut step creeps nearer the fold; the large scene's hopeless move at 40 x 20 failed
  after 17 cutbacks, the same element blocking 13 of them, where a successful move in the tests
  had at most 2 at one element) the move fails through the operators' ``fail`` (a
  :class:`~tofsi.core.errors.NumericalError` with the report and, where known, the element the
  last trial inverted).

Every decision reads norms and dot products of whole (replicated) vectors, so ranks that hold the
same bits take the same decisions.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from movers.base import MoveReport
from movers.failure import Trouble, describe_break
from tofsi.core.iteration import forcing_term

log = logging.getLogger(__name__)
ROUND_OFF = 1e3 * np.finfo(float).eps      # attainable |D| relative to the forces' size
BLOCKED_CUTBACKS = 8                       # cut steps one element may block before the move fails


@dataclass(frozen=True)
class NewtonSettings:
    """The load-stepping Newton's parameters (the names and defaults of :class:`movers.yeoh.YeohParams`)."""

    increments: int = 1          # initial number of load steps
    newton_tol: float = 1e-10    # |D_free| relative to the force scale
    max_newton: int = 25         # Newton iterations per step
    min_increment: float = 1e-4  # smallest load step before failing
    max_cutbacks: int = 40       # step cuts before failing

    @classmethod
    def of(cls, params) -> "NewtonSettings":
        """The settings in a mover's ``params``; a mover without some of them takes these defaults."""
        return cls(**{key: getattr(params, key, default) for key, default in cls().__dict__.items()})


class NewtonOperators(Protocol):
    """What :class:`LoadStepNewton` needs of the equations. ``state`` is whatever ``evaluate``
    returns (element residuals and tangents); vectors are (2n,), replicated where distributed."""

    target: np.ndarray           # the full motion t (2n,) (zero off the prescribed dofs without a blend)
    fixed: np.ndarray            # the fixed dofs' indices

    def evaluate(self, x: np.ndarray, tangent: bool = True):
        """The state at ``x``; None when an element is invalid (anywhere)."""

    def forces(self, state) -> np.ndarray:
        """The assembled internal forces ``R`` of ``state``."""

    def residual(self, state, x: np.ndarray, load: float) -> np.ndarray:
        """``D(x)`` at ``load``: zero on the fixed dofs."""

    def jump(self, state, boundary_step: np.ndarray) -> np.ndarray:
        """Free-row response ``W K_fp d_p`` to moving the fixed dofs by ``d_p``."""

    def solve(self, state, rhs: np.ndarray, rtol: float) -> np.ndarray:
        """``A^-1 rhs`` to ``rtol``, ``A = P_f (W K + S_c) P_f + P_p`` the tangent of ``state``."""

    def nearer(self, x0: np.ndarray) -> bool:
        """True when ``x0`` is nearer than zero to the target on the dofs the motion prescribes."""

    def broken(self, x: np.ndarray) -> dict | None:
        """The element ``x`` inverts (:func:`movers.failure.broken_element`), None when none."""

    def record(self, report: MoveReport, x: np.ndarray, load: float, planned: int) -> None:
        """An accepted step to ``load`` (``planned`` steps at first)."""

    def fail(self, report: MoveReport, x: np.ndarray | None, message: str, load: float, broken) -> None:
        """Raise the move's failure (``x`` the last accepted displacement at ``load``)."""


class LoadStepNewton:
    """One move: ``ops`` the equations (:class:`NewtonOperators`), ``settings`` the
    :class:`NewtonSettings`, ``report`` the :class:`~movers.base.MoveReport` it fills,
    ``label`` the logs' name of the mover."""

    def __init__(self, ops: NewtonOperators, settings: NewtonSettings, report: MoveReport, label: str):
        self.ops, self.p, self.report, self.label = ops, settings, report, label

    def move(self, initial: np.ndarray | None = None) -> np.ndarray:
        """The converged ``x`` (2n,): from ``initial`` when that works, else in load steps from zero."""
        x = None if initial is None else self.warm_start(np.asarray(initial, dtype=float).reshape(-1))
        return self.load_steps() if x is None else x

    def warm_start(self, x0: np.ndarray) -> np.ndarray | None:
        """Newton from ``x0`` to the full load; None when ``x0`` is not nearer than zero or fails."""
        ops = self.ops
        if x0.shape != ops.target.shape or not np.all(np.isfinite(x0)) or not ops.nearer(x0):
            return None
        state = ops.evaluate(x0)
        if state is None:
            return None
        x, _, history, why = self.increment(x0, state, 1.0)
        self.report.residual_history.append(history)
        if x is None:
            log.info("%s: the warm start failed (%s); load steps from zero", self.label, why)
            return None
        self.report.warm_start = True
        ops.record(self.report, x, 1.0, 1)
        return x

    def load_steps(self) -> np.ndarray:
        """The motion applied in load steps from zero, each cut in half when it fails."""
        ops, p, report = self.ops, self.p, self.report
        x = np.zeros_like(ops.target)
        state = ops.evaluate(x)
        if state is None:
            ops.fail(report, None, "the reference mesh is invalid", 0.0, ops.broken(x))
        load, step = 0.0, 1.0 / p.increments
        blocked: dict[int, int] = {}               # cut steps each element blocked (inverted)
        while load < 1.0 - 1e-14:
            step = min(step, 1.0 - load)
            x_new, state_new, history, why = self.increment(x, state, load + step)
            report.residual_history.append(history)
            if x_new is None:
                report.cutbacks += 1
                step *= 0.5
                log.info("%s: increment at load %.4g failed (%s); cut to %.3g", self.label, load, why, step)
                element = None if why.broken is None else why.broken["element"]
                blocked[element] = blocked.get(element, 0) + 1
                if element is not None and blocked[element] >= BLOCKED_CUTBACKS:
                    ops.fail(report, x, f"no convergence beyond load {load:.4g}: {why}; that element blocked "
                             f"{blocked[element]} of {report.cutbacks} cut steps (the mesh folds there)",
                             load, why.broken)
                if step < p.min_increment or report.cutbacks > p.max_cutbacks:
                    ops.fail(report, x, f"no convergence beyond load {load:.4g} after {report.cutbacks} "
                             f"cutbacks (last: {why})", load, why.broken)
                continue
            x, state, load = x_new, state_new, load + step
            ops.record(report, x, load, p.increments)
            if len(history) <= 4:                # easy increment: take a longer next one
                step *= 1.5
        return x

    def tolerance(self, state, scale: float) -> float:
        """Newton's target for ``|D_free|``: ``newton_tol`` relative to the larger of ``scale``
        and the internal forces (the reactions, and the blended rows' balancing forces),
        never below round-off."""
        forces = np.linalg.norm(self.ops.forces(state))
        size = self.ops.target.size
        return max(self.p.newton_tol * max(scale, forces), ROUND_OFF * np.sqrt(size) * forces)

    def increment(self, x0: np.ndarray, state0, load: float):
        """Newton solve of the equations at ``load`` from ``x0`` (its state ``state0``), starting
        with the tangent predictor of the step of the fixed dofs to ``load t``; returns
        ``(x or None, its state, |D_free| history, reason)``."""
        ops, p, report, fixed = self.ops, self.p, self.report, self.ops.fixed
        boundary_step = load * ops.target - x0             # used on the fixed dofs only
        jump = ops.jump(state0, boundary_step)
        r0 = ops.residual(state0, x0, load)
        rhs = -(r0 + jump)
        rhs[fixed] = boundary_step[fixed]
        x = x0 + ops.solve(state0, rhs, 1e-3)                # tangent predictor (loose)
        x[fixed] = load * ops.target[fixed]                  # exactly
        report.linear_solves += 1
        R_fixed = ops.forces(state0)[fixed]
        scale = max(np.linalg.norm(jump), np.linalg.norm(r0), np.linalg.norm(R_fixed), 1e-300)
        history: list[float] = []
        if not np.any(boundary_step[fixed]) and np.linalg.norm(r0) <= self.tolerance(state0, scale):
            return x0, state0, [float(np.linalg.norm(r0))], ""      # already there (a warm start)
        state = ops.evaluate(x)
        if state is None:
            broken = ops.broken(x)
            return None, None, history, Trouble(f"the predictor to load {load:.4g} {describe_break(broken)}",
                                                broken)
        for it in range(p.max_newton + 1):
            r = ops.residual(state, x, load)
            norm = float(np.linalg.norm(r))
            history.append(norm)
            target = self.tolerance(state, scale)
            log.info("%s Newton %d: |R| = %.3e (target %.2e, scale %.2e)", self.label, it, norm, target, scale)
            if not np.isfinite(norm):
                return None, None, history, Trouble(f"non-finite residual at load {load:.4g} on a valid "
                                                    "mesh (no element inverted)")
            if norm <= target:
                return x, state, history, ""
            if it == p.max_newton:
                return None, None, history, Trouble(f"{p.max_newton} Newton iterations at load {load:.4g} "
                                                    "did not reach the tolerance (no element inverted)")
            dx = ops.solve(state, -r, forcing_term(history, target))
            dx[fixed] = 0.0
            report.linear_solves += 1
            report.newton_iterations += 1
            x_new = self.line_search(x, dx, r, norm, load)
            if x_new is None:
                broken = ops.broken(x + dx)               # what the full Newton step does to the mesh
                what = (f"the full Newton step {describe_break(broken)}" if broken
                        else "Newton diverged on a valid mesh (no element inverted)")
                return None, None, history, Trouble(f"line search found no decrease at load {load:.4g}: {what}",
                                                    broken)
            x = x_new
            state = ops.evaluate(x)
            if state is None:                             # valid as a trial: cannot happen
                return None, None, history, Trouble(f"an accepted step at load {load:.4g} is invalid")
        return None, None, history, Trouble("unreachable")

    def line_search(self, x: np.ndarray, dx: np.ndarray, r: np.ndarray, norm: float, load: float):
        """Step length along ``dx``: returns the new ``x``, or None.

        ``g(alpha) = dx . D(x + alpha dx)`` is the slope of the energy along the
        step (without a blend); ``g(0) = dx . r < 0``. Accept the full step when
        the slope has dropped to a tenth; otherwise try the secant root
        ``g0 / (g0 - g(1))`` (clipped to [0.1, 4]: the step may be shortened or, when
        the energy is nearly quartic, extended) once, then halve. An accepted step must
        reduce ``|D|`` and invert no element. Trials evaluate the residual alone (the
        caller evaluates the tangent where it lands).
        """
        ops = self.ops

        def trial(alpha):
            xt = x + alpha * dx
            state = ops.evaluate(xt, tangent=False)
            if state is None:
                return xt, None, None
            rt = ops.residual(state, xt, load)
            return xt, float(dx @ rt), float(np.linalg.norm(rt))

        g0 = float(dx @ r)
        alphas = [1.0]
        xt, g1, n1 = trial(1.0)
        if g1 is not None and n1 < norm and (g0 >= 0 or abs(g1) <= 0.1 * abs(g0)):
            return xt
        if g1 is not None and g0 < 0 and g1 != g0:
            alphas.append(float(np.clip(g0 / (g0 - g1), 0.1, 4.0)))
        alphas += [0.5 ** k for k in range(1, 7)]
        best = (xt, n1) if g1 is not None and n1 < (1 - 1e-4) * norm else None
        for alpha in alphas[1:]:
            xa, ga, na = trial(alpha)
            if ga is not None and na < (1 - 1e-4 * min(alpha, 1.0)) * norm and (best is None or na < best[1]):
                return xa
            if best is not None:
                return best[0]
        return None if best is None else best[0]
