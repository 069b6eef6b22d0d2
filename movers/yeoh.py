"""Yeoh hyperelastic mover: total Lagrangian, Newton from one load step or a nearby solution.

Unknown: the mesh displacement ``x`` (2n). Residual (internal forces of the
reference mesh, 2x2 Gauss points):

    R_a,i(x) = sum_g w_g det J0_g P_iJ dN_a/dX_J,   P = F S,   F = I + grad0 x,

with ``S`` from :mod:`movers.yeoh_material` (``A20`` times the quad's
stiffening factor). The tangent is the consistent one, ``dR/dx`` through the
first elasticity tensor ``A = dP/dF``; residual and tangent come from one
pass of :class:`movers.yeoh_kernel.YeohKernel`.

The prescribed motion is applied as ``lambda u`` with ``lambda`` stepping from
0 to 1, in one step unless ``increments`` says otherwise. Each step starts
with a tangent predictor (the boundary step and the free nodes' linear
response), then Newton corrections with a
line search on the energy's slope along the step, ``g(alpha) = dx . R(x + alpha dx)``
(Crisfield's secant search: the step may be shortened or, when the energy is
nearly quartic as with a large A20, extended up to 4x), falling back to
halving; every trial refuses an element whose ``det F`` or corner Jacobian
is not positive, and an accepted step must reduce ``|R_free|``. A step that fails
(inversion, no decrease, iteration limit) is cut in half; the mover stops
with a diagnostic when the step falls below ``min_increment`` or after
``max_cutbacks`` cuts. A move given ``initial``, the solution of a nearby
motion (the previous design's, or the previous coupling sweep's), makes one
step from there straight to the full motion, and falls back to load steps
from zero when that fails. Tangent systems are solved by a
:class:`~tofsi.linalg.RecyclingSolver` (factorize, or build an AMG
hierarchy, rarely; precondition the Krylov solves of the tangents in between),
which a move may inherit from an earlier one (``solver``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from movers.base import Mover, MoveReport, MoveResult, element_apply, quality_record
from movers.problem import MotionProblem
from movers.failure import Trouble, broken_element, describe_break
from movers.incremental import system
from movers.yeoh_kernel import YeohKernel
from tofsi.mesh import quality
from tofsi.core.config import option
from tofsi.core.errors import NumericalError
from tofsi.fem.assembly import assemble_vector
from tofsi.core.iteration import forcing_term
from tofsi.linalg import RecyclingSolver

log = logging.getLogger(__name__)
ROUND_OFF = 1e3 * np.finfo(float).eps      # attainable |R| relative to the forces' size


@dataclass(frozen=True)
class YeohParams:
    renamed_keys = {"linear_solver": "tangent_solver"}     # the old name, accepted with a warning
    A10: float = option(1.0, gt=0, doc="first Yeoh coefficient [Pa]")
    A20: float = option(1e3, ge=0, doc="second Yeoh coefficient [Pa] (stiffened per layer)")
    A30: float = option(0.0, ge=0, doc="third Yeoh coefficient [Pa]")
    kappa: float = option(1.0, gt=0, doc="bulk coefficient [Pa]")
    increments: int = option(1, ge=1, le=100_000, doc="initial number of load increments "
                             "(the result does not depend on it; more make Newton easier)")
    newton_tol: float = option(1e-10, gt=0, lt=1, doc="|R_free| relative to the force scale")
    max_newton: int = option(25, ge=1, le=1000, doc="Newton iterations per increment")
    min_increment: float = option(1e-4, gt=0, lt=1, doc="smallest load increment before failing")
    max_cutbacks: int = option(40, ge=0, le=10_000, doc="increment cuts before failing")
    tangent_solver: str = option("direct", choices=("direct", "amg"),
                                 doc="the tangent's linear solver: sparse LU or AMG-CG")
    linear_tol: float = option(1e-10, gt=0, lt=1e-3, doc="relative tolerance of recycled iterative solves")


class Equations:
    """The Yeoh mover's equations at load ``lambda``: ``D(x) = 0``.

    Free rows ``W R(x) + S_c (x - lambda u)`` (``W = 1``, ``S_c = 0`` without a
    blend), fixed rows ``x_p = lambda u_p``; the Jacobian is ``W K + S_c`` with
    identity rows on the fixed dofs.
    """

    def __init__(self, kernel: YeohKernel, blend, target: np.ndarray):
        self.kernel, self.blend, self.target = kernel, blend, target
        self.bc, self.dofs = kernel.problem.bc, kernel.problem.dofs

    def residual(self, Re: np.ndarray, x: np.ndarray, load: float) -> np.ndarray:
        r = assemble_vector(self.dofs, Re, x.size)
        if self.blend is not None:
            r = self.blend.residual(r, x, load * self.target)
        return self.bc.homogenize(r)

    def matrix(self, Ke: np.ndarray):
        return system(self.bc, Ke, self.dofs, self.blend)

    def jump(self, Ke: np.ndarray, boundary_step: np.ndarray) -> np.ndarray:
        """Free-row response ``W K_fp d_p`` to moving the fixed dofs by ``d_p``."""
        d = np.zeros_like(boundary_step)
        d[self.bc.fixed] = boundary_step[self.bc.fixed]
        r = element_apply(Ke, d, self.dofs)
        return self.bc.homogenize(r if self.blend is None else self.blend.weighted(r))

    def nearer(self, x0: np.ndarray) -> bool:
        """True when ``x0`` is nearer than zero to the full motion on the dofs the motion
        prescribes (the fixed ones, and the blended ones)."""
        carried = self.bc.is_fixed if self.blend is None else self.bc.is_fixed | (self.blend.diag > 0)
        return bool(np.linalg.norm((self.target - x0)[carried]) < np.linalg.norm(self.target[carried]))


class YeohMover(Mover):
    """Yeoh hyperelastic mesh, Newton-Raphson with load stepping and cutback."""

    name = "yeoh"
    Params = YeohParams

    def element_residual(self, problem: MotionProblem, x: np.ndarray, factors, tangent: bool = True):
        """Internal forces ``(Em, 8)`` and consistent tangents of the reference mesh at ``x``."""
        Re, Ke, det = YeohKernel(problem, self.params, factors).evaluate(np.asarray(x).reshape(-1), tangent)
        if Re is None:
            raise NumericalError("yeoh residual: an element is inverted (det F <= 0)",
                                 {"min_det_F": float(det.min())})
        return Re, Ke

    warm_starts = True

    def move(self, problem: MotionProblem, prescribed: np.ndarray, progress=None,
             initial: np.ndarray | None = None, solver: RecyclingSolver | None = None) -> MoveResult:
        """Displacement with the fixed nodes at ``prescribed``.

        initial : ``(n, 2)`` a mesh displacement for a nearby motion (e.g. the
            previous design's or coupling sweep's) to start from: one Newton solve
            goes straight to the full motion (no load steps) when its prescribed
            values are nearer to the target than zero is; when that fails, and
            without ``initial``, the motion is applied in load steps from zero.
        solver : the :class:`~tofsi.linalg.RecyclingSolver` of an earlier move of
            the same mesh, whose factorization (or hierarchy) preconditions this
            move's systems until it goes stale.
        The result does not depend on either (to ``newton_tol``).
        """
        target, t0 = self._start(problem, prescribed)
        report = MoveReport(mover=self.name)
        blend = self.blend(problem)
        eqs = Equations(YeohKernel(problem, self.params), blend, target)
        solver = self._solver(problem) if solver is None else solver
        counts = solver.factorizations, solver.krylov_iterations
        x = None
        if initial is not None:
            x = self._warm_start(eqs, solver, np.asarray(initial, dtype=float).reshape(-1), report, progress)
        if x is None:
            x = self._load_steps(eqs, solver, report, progress, t0)
        result = self._finish(report, problem, x, t0, solver, blend=blend, target=target)
        report.factorizations -= counts[0]               # this move's own
        report.krylov_iterations -= counts[1]
        return result

    def _warm_start(self, eqs: Equations, solver, x0: np.ndarray, report: MoveReport, progress):
        """Newton from ``x0`` to the full load; None when ``x0`` is not nearer than zero or fails."""
        if x0.shape != eqs.target.shape or not np.all(np.isfinite(x0)) or not eqs.nearer(x0):
            return None
        Re, Ke, det_min = eqs.kernel.evaluate(x0)
        if Re is None or not self._valid(eqs.kernel, x0, det_min):
            return None
        x, _, history, why = self._increment(eqs, solver, x0, (Re, Ke), 1.0, report)
        report.residual_history.append(history)
        if x is None:
            log.info("yeoh: the warm start failed (%s); load steps from zero", why)
            return None
        report.warm_start = True
        self._record(report, eqs.kernel.problem, x, 1.0, 1, progress)
        return x

    def _load_steps(self, eqs: Equations, solver, report: MoveReport, progress, t0: float) -> np.ndarray:
        """The motion applied in load steps from zero, each cut in half when it fails."""
        p, problem = self.params, eqs.kernel.problem
        x = np.zeros_like(eqs.target)
        state = eqs.kernel.evaluate(x)[:2]              # element residuals and tangents at x
        load, step = 0.0, 1.0 / p.increments
        while load < 1.0 - 1e-14:
            step = min(step, 1.0 - load)
            x_new, state_new, history, why = self._increment(eqs, solver, x, state, load + step, report)
            report.residual_history.append(history)
            if x_new is None:
                report.cutbacks += 1
                step *= 0.5
                log.info("yeoh: increment at load %.4g failed (%s); cut to %.3g", load, why, step)
                if step < p.min_increment or report.cutbacks > p.max_cutbacks:
                    self._fail(report, problem, x, f"no convergence beyond load {load:.4g} after "
                               f"{report.cutbacks} cutbacks (last: {why})", t0, load, why.broken)
                continue
            x, state, load = x_new, state_new, load + step
            self._record(report, problem, x, load, p.increments, progress)
            if len(history) <= 4:                # easy increment: take a longer next one
                step *= 1.5
        return x

    @staticmethod
    def _record(report: MoveReport, problem: MotionProblem, x, load: float, planned: int, progress) -> None:
        report.increments += 1
        record = quality_record(problem, x.reshape(-1, 2), load)
        report.quality.append(record)
        if progress:
            progress(report.increments, planned, record)

    def _line_search(self, eqs: Equations, x, dx, r, norm, load):
        """Step length along ``dx``: returns the new ``x``, or None.

        ``g(alpha) = dx . D(x + alpha dx)`` is the slope of the energy along the
        step (without a blend); ``g(0) = dx . r < 0``. Accept the full step when
        the slope has dropped to a tenth; otherwise try the secant root
        ``g0 / (g0 - g(1))`` (clipped to [0.1, 4]) once, then halve. An accepted
        step must reduce ``|D|`` and invert no element. Trials evaluate the
        residual alone (the caller evaluates the tangent where it lands).
        """
        kernel = eqs.kernel

        def trial(alpha):
            xt = x + alpha * dx
            Re_t, _, det_t = kernel.evaluate(xt, tangent=False)
            if Re_t is None or not self._valid(kernel, xt, det_t):
                return xt, None, None
            rt = eqs.residual(Re_t, xt, load)
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

    def _valid(self, kernel: YeohKernel, x: np.ndarray, det_min: np.ndarray) -> bool:
        if np.any(det_min <= 0.0):
            return False
        P = kernel.problem
        return not np.any(quality.inverted(P.points + x.reshape(-1, 2), P.quads))

    def _tolerance(self, eqs: Equations, Re: np.ndarray, scale: float) -> float:
        """Newton's target for ``|D_free|``: ``newton_tol`` relative to the larger of ``scale``
        and the internal forces (the reactions, and the blended rows' balancing forces),
        never below round-off."""
        forces = np.linalg.norm(assemble_vector(eqs.dofs, Re, eqs.target.size))
        return max(self.params.newton_tol * max(scale, forces), ROUND_OFF * np.sqrt(eqs.target.size) * forces)

    def _increment(self, eqs: Equations, solver: RecyclingSolver, x0: np.ndarray, state0,
                   load: float, report: MoveReport):
        """Newton solve of the equations at ``load`` from ``x0`` (element residuals and
        tangents ``state0``), starting with the tangent predictor of the step of the
        fixed dofs to ``load u``; returns (x or None, its (Re, Ke), |D_free| history, reason)."""
        p, bc = self.params, eqs.bc
        Re, Ke = state0
        boundary_step = load * eqs.target - x0             # used on the fixed dofs only
        jump = eqs.jump(Ke, boundary_step)
        r0 = eqs.residual(Re, x0, load)
        rhs = -(r0 + jump)
        rhs[bc.fixed] = boundary_step[bc.fixed]
        x = x0 + solver.solve(eqs.matrix(Ke), rhs, rtol=1e-3)   # tangent predictor (loose)
        x[bc.fixed] = load * eqs.target[bc.fixed]             # exactly
        report.linear_solves += 1
        R_fixed = assemble_vector(eqs.dofs, Re, x0.size)[bc.fixed]
        scale = max(np.linalg.norm(jump), np.linalg.norm(r0), np.linalg.norm(R_fixed), 1e-300)
        history: list[float] = []
        if not np.any(boundary_step[bc.fixed]) and np.linalg.norm(r0) <= self._tolerance(eqs, Re, scale):
            return x0, state0, [float(np.linalg.norm(r0))], ""      # already there (a warm start)
        Re, Ke, det_min = eqs.kernel.evaluate(x)
        if Re is None or not self._valid(eqs.kernel, x, det_min):
            broken = broken_element(eqs.kernel.problem, x, det_min)
            return None, None, history, Trouble(f"the predictor to load {load:.4g} {describe_break(broken)}",
                                                broken)
        for it in range(p.max_newton + 1):
            r = eqs.residual(Re, x, load)
            norm = float(np.linalg.norm(r))
            history.append(norm)
            target = self._tolerance(eqs, Re, scale)
            log.info("yeoh Newton %d: |R| = %.3e (target %.2e, scale %.2e)", it, norm, target, scale)
            if not np.isfinite(norm):
                return None, None, history, Trouble(f"non-finite residual at load {load:.4g} on a valid "
                                                    "mesh (no element inverted)")
            if norm <= target:
                return x, (Re, Ke), history, ""
            if it == p.max_newton:
                return None, None, history, Trouble(f"{p.max_newton} Newton iterations at load {load:.4g} "
                                                    "did not reach the tolerance (no element inverted)")
            dx = solver.solve(eqs.matrix(Ke), -r, rtol=forcing_term(history, target))
            dx[bc.fixed] = 0.0
            report.linear_solves += 1
            report.newton_iterations += 1
            x_new = self._line_search(eqs, x, dx, r, norm, load)
            if x_new is None:
                full = x + dx                             # what the Newton step does to the mesh
                broken = broken_element(eqs.kernel.problem, full, eqs.kernel.evaluate(full, tangent=False)[2])
                what = (f"the full Newton step {describe_break(broken)}" if broken
                        else "Newton diverged on a valid mesh (no element inverted)")
                return None, None, history, Trouble(f"line search found no decrease at load {load:.4g}: {what}",
                                                    broken)
            x = x_new
            Re, Ke, _ = eqs.kernel.evaluate(x)
        return None, None, history, Trouble("unreachable")
