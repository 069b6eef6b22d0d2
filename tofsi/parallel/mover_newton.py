"""Newton for the mesh mover by slabs: load steps, cutbacks, a secant line search (the Yeoh mover's).

The algorithm of :class:`movers.yeoh.YeohMover`'s move, on the distributed operators of
:class:`~tofsi.parallel.slab_mover.SlabMover` (element kernels on each rank's slab, residuals
summed over ranks, tangents factorized by MUMPS across the ranks):

* a move given a nearby displacement (the previous sweep's or design's) makes one Newton solve
  from there straight to the full motion when its prescribed values are nearer the target than
  zero is; when that fails, and without one, the motion ``lambda t`` is applied in load steps
  ``lambda = 0 -> 1`` (``increments`` at first; an easy step lengthens the next by 1.5);
* each step starts with the tangent predictor (the fixed dofs' step and the free dofs' linear
  response ``-A_ff^-1 (D + W K_fp d_p)``, solved to 1e-3), then Newton corrections ``A dx = -D``
  (solved to Eisenstat-Walker's forcing term; GMRES preconditioned by an earlier step's MUMPS
  factors, refactorized when they go stale, as the serial mover's recycling solver) with the line
  search on the energy's slope ``g(alpha) = dx . D(x + alpha dx)`` (accept ``alpha = 1`` when
  ``|g|`` fell to a tenth, else the secant root clipped to [0.1, 4] once, then halving); a trial
  must be valid on every rank and reduce ``|D|``;
* converged when ``|D_free| <= max(newton_tol max(scale, |R|), 1e3 eps sqrt(2n) |R|)``, ``scale``
  the step's initial residual, boundary response and reactions;
* a failed step is cut in half; below ``min_increment`` or past ``max_cutbacks`` cuts the move
  fails with a :class:`~tofsi.core.errors.NumericalError` holding its report -- on every rank
  alike, since every decision reads replicated values with the same bits.

A mover without these parameters (linear elasticity, the spring in one increment) takes
Yeoh's defaults; its residual is linear and its tangent constant (the kept factors are exact),
so the predictor and at most a Newton step or two solve it.
"""

from __future__ import annotations

import logging

import numpy as np

from tofsi.core.errors import NumericalError
from tofsi.core.iteration import forcing_term

log = logging.getLogger(__name__)
ROUND_OFF = 1e3 * np.finfo(float).eps        # attainable |D| relative to the forces' size
DEFAULTS = {"increments": 1, "newton_tol": 1e-10, "max_newton": 25, "min_increment": 1e-4, "max_cutbacks": 40}


class SlabNewton:
    """One move of ``mover`` (a :class:`~tofsi.parallel.slab_mover.SlabMover`) at design data ``design``
    towards the prescribed motion ``target`` (2n,)."""

    def __init__(self, mover, design, target: np.ndarray):
        self.m, self.d, self.target = mover, design, target
        p = mover.params
        self.p = {key: getattr(p, key, default) for key, default in DEFAULTS.items()}
        self.report = {"mover": mover.mover.name, "converged": False, "increments": 0, "newton_iterations": 0,
                       "linear_solves": 0, "factorizations": 0, "krylov_iterations": 0, "cutbacks": 0,
                       "warm_start": False, "residual_history": [], "message": ""}

    def move(self, initial: np.ndarray | None):
        """``(x (2n,), report)``; raises NumericalError (the report in its diagnostic) on failure."""
        start, krylov = self.m.matrix.factorizations, self.m.matrix.krylov_iterations
        x = None if initial is None else self.warm_start(initial)
        if x is None:
            x = self.load_steps()
        self.report.update(converged=True, factorizations=self.m.matrix.factorizations - start,
                           krylov_iterations=self.m.matrix.krylov_iterations - krylov)
        return x, self.report

    # ---- the pieces ------------------------------------------------------------------------------
    def residual(self, e, x, load):
        return self.m.residual(self.d, e.R, x, load * self.target)

    def jump(self, Ke, step):
        """Free-row response ``W K_fp d_p`` to moving the fixed dofs by ``step``."""
        v = np.zeros_like(step)
        v[self.m.fixed] = step[self.m.fixed]
        r = self.d.weight * self.m.apply(self.d, Ke, v)
        r[self.m.fixed] = 0.0
        return r

    def tolerance(self, e, scale: float) -> float:
        forces = float(np.linalg.norm(e.R))
        return max(self.p["newton_tol"] * max(scale, forces), ROUND_OFF * np.sqrt(e.R.size) * forces)

    def linear_solve(self, Ke, rhs, rtol: float):
        """The tangent's solve to ``rtol``: GMRES preconditioned by an earlier step's factors,
        refactorized when they went stale (:meth:`~tofsi.parallel.slab_matrix.SlabMatrix.solve`)."""
        self.m.assemble(self.d, Ke)
        self.report["linear_solves"] += 1
        return self.m.solve(rhs, rtol=rtol)

    def nearer(self, x0) -> bool:
        carried = self.m.is_fixed | (self.d.diag > 0)
        return bool(np.linalg.norm((self.target - x0)[carried]) < np.linalg.norm(self.target[carried]))

    # ---- the move ----------------------------------------------------------------------------------
    def warm_start(self, x0):
        """Newton from ``x0`` to the full load; None when ``x0`` is not nearer than zero or fails."""
        if x0.shape != self.target.shape or not np.all(np.isfinite(x0)) or not self.nearer(x0):
            return None
        e = self.m.evaluate(self.d, x0)
        if e is None:
            return None
        x, _, history, why = self.increment(x0, e, 1.0)
        self.report["residual_history"].append(history)
        if x is None:
            log.info("mover by slabs: the warm start failed (%s); load steps from zero", why)
            return None
        self.report["warm_start"] = True
        self.report["increments"] += 1
        return x

    def load_steps(self):
        x = np.zeros_like(self.target)
        e = self.m.evaluate(self.d, x)
        if e is None:
            self.fail("the reference mesh is invalid", 0.0)
        load, step = 0.0, 1.0 / self.p["increments"]
        while load < 1.0 - 1e-14:
            step = min(step, 1.0 - load)
            x_new, e_new, history, why = self.increment(x, e, load + step)
            self.report["residual_history"].append(history)
            if x_new is None:
                self.report["cutbacks"] += 1
                step *= 0.5
                log.info("mover by slabs: increment at load %.4g failed (%s); cut to %.3g", load, why, step)
                if step < self.p["min_increment"] or self.report["cutbacks"] > self.p["max_cutbacks"]:
                    self.fail(f"no convergence beyond load {load:.4g} after {self.report['cutbacks']} "
                              f"cutbacks (last: {why})", load)
                continue
            x, e, load = x_new, e_new, load + step
            self.report["increments"] += 1
            if len(history) <= 4:                 # easy increment: take a longer next one
                step *= 1.5
        return x

    def fail(self, message: str, load: float):
        self.report["message"] = message
        raise NumericalError(f"{self.report['mover']} mover (by slabs): {message}",
                             {"report": dict(self.report), "load": load})

    def increment(self, x0, e0, load: float):
        """Newton at ``load`` from ``x0`` (its evaluation ``e0``), after the tangent predictor;
        ``(x or None, its evaluation, |D_free| history, reason)``."""
        fixed = self.m.fixed
        step = load * self.target - x0                       # used on the fixed dofs only
        jump = self.jump(e0.Ke, step)
        r0 = self.residual(e0, x0, load)
        rhs = -(r0 + jump)
        rhs[fixed] = step[fixed]
        scale = max(np.linalg.norm(jump), np.linalg.norm(r0), np.linalg.norm(e0.R[fixed]), 1e-300)
        if not np.any(step[fixed]) and np.linalg.norm(r0) <= self.tolerance(e0, scale):
            return x0, e0, [float(np.linalg.norm(r0))], ""            # already there (a warm start)
        x = x0 + self.linear_solve(e0.Ke, rhs, 1e-3)             # tangent predictor (loose)
        x[fixed] = load * self.target[fixed]
        e = self.m.evaluate(self.d, x)
        history: list[float] = []
        if e is None:
            return None, None, history, f"the predictor to load {load:.4g} inverts an element"
        for it in range(self.p["max_newton"] + 1):
            r = self.residual(e, x, load)
            norm = float(np.linalg.norm(r))
            history.append(norm)
            target = self.tolerance(e, scale)
            log.info("mover by slabs, Newton %d: |D| = %.3e (target %.2e)", it, norm, target)
            if not np.isfinite(norm):
                return None, None, history, f"non-finite residual at load {load:.4g}"
            if norm <= target:
                return x, e, history, ""
            if it == self.p["max_newton"]:
                return None, None, history, f"{it} Newton iterations at load {load:.4g} did not converge"
            dx = self.linear_solve(e.Ke, -r, forcing_term(history, target))
            dx[fixed] = 0.0
            self.report["newton_iterations"] += 1
            found = self.line_search(x, dx, r, norm, load)
            if found is None:
                return None, None, history, f"line search found no decrease at load {load:.4g}"
            x = found
            e = self.m.evaluate(self.d, x)
            if e is None:                                              # valid as a trial: cannot happen
                return None, None, history, f"an invalid element at load {load:.4g}"
        return None, None, history, "unreachable"

    def line_search(self, x, dx, r, norm: float, load: float):
        """The new ``x`` along ``dx``, or None (Yeoh's secant search on the energy's slope)."""
        def trial(alpha):
            xt = x + alpha * dx
            et = self.m.evaluate(self.d, xt, tangent=False)
            if et is None:
                return xt, None, None
            rt = self.residual(et, xt, load)
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
