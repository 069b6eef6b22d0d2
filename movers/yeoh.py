"""Yeoh hyperelastic mover: total Lagrangian, Newton with load increments.

Unknown: the mesh displacement ``x`` (2n). Residual (internal forces of the
reference mesh, 2x2 Gauss points):

    R_a,i(x) = sum_g w_g det J0_g P_iJ dN_a/dX_J,   P = F S,   F = I + grad0 x,

with ``S`` from :mod:`movers.yeoh_material` (``A20`` times the quad's
stiffening factor). The tangent is the consistent one,
``K = sum_g w det J0 (B_L^T D B_L + grad0 N^T S grad0 N (x) I)``.

The prescribed motion is applied as ``lambda u`` with ``lambda`` stepping from
0 to 1. Each increment starts with a tangent predictor (the boundary step and
the free nodes' linear response), then Newton corrections with a
line search on the energy's slope along the step, ``g(alpha) = dx . R(x + alpha dx)``
(Crisfield's secant search: the step may be shortened or, when the energy is
nearly quartic as with a large A20, extended up to 4x), falling back to
halving; every trial refuses an element whose ``det F`` or corner Jacobian
is not positive, and an accepted step must reduce ``|R_free|``. An increment that fails
(inversion, no decrease, iteration limit) is cut in half; the mover stops
with a diagnostic when the increment falls below ``min_increment`` or after
``max_cutbacks`` cuts. Tangent systems are solved by a
:class:`~tofsi.linalg.RecyclingSolver` (factorize rarely, GMRES in between).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from movers.base import MotionProblem, Mover, MoveReport, MoveResult, element_apply, quality_record
from movers.incremental import system
from movers.yeoh_material import stress, stress_and_tangent
from tofsi import quality
from tofsi.config import option
from tofsi.errors import NumericalError
from tofsi.fem.assembly import assemble_vector, weighted_gram
from tofsi.fem.geometry import physical_gradients
from tofsi.fem.quadrature import gauss_square
from tofsi.iteration import forcing_term
from tofsi.linalg import RecyclingSolver

log = logging.getLogger(__name__)
ROUND_OFF = 1e3 * np.finfo(float).eps      # attainable |R| relative to the forces' size


@dataclass(frozen=True)
class YeohParams:
    A10: float = option(1.0, gt=0, doc="first Yeoh coefficient [Pa]")
    A20: float = option(1e3, ge=0, doc="second Yeoh coefficient [Pa] (stiffened per layer)")
    A30: float = option(0.0, ge=0, doc="third Yeoh coefficient [Pa]")
    kappa: float = option(1.0, gt=0, doc="bulk coefficient [Pa]")
    increments: int = option(2, ge=1, le=100_000, doc="initial number of load increments "
                             "(the result does not depend on it; more make Newton easier)")
    newton_tol: float = option(1e-10, gt=0, lt=1, doc="|R_free| relative to the force scale")
    max_newton: int = option(25, ge=1, le=1000, doc="Newton iterations per increment")
    min_increment: float = option(1e-4, gt=0, lt=1, doc="smallest load increment before failing")
    max_cutbacks: int = option(40, ge=0, le=10_000, doc="increment cuts before failing")
    linear_solver: str = option("direct", choices=("direct", "amg"), doc="sparse LU or AMG-CG")
    linear_tol: float = option(1e-10, gt=0, lt=1e-3, doc="relative tolerance of recycled iterative solves")


class YeohKernel:
    """Batched residual and tangent of the Yeoh mesh on a fixed reference mesh."""

    def __init__(self, problem: MotionProblem, params: YeohParams, stiffening=None):
        points, weights = gauss_square(2)
        Xe = problem.points[problem.quads]
        self.grad0, det0 = physical_gradients(Xe, 1, points)      # (E, G, 4, 2), (E, G)
        self.wdet = det0 * weights
        self.problem, self.p = problem, params
        factors = problem.stiffening if stiffening is None else stiffening
        self.A20 = (params.A20 * factors)[:, None]                 # (E, 1)

    def deformation_gradient(self, x: np.ndarray) -> np.ndarray:
        """``F = I + sum_a u_a (x) grad0 N_a`` ``(E, G, 2, 2)``."""
        ue = x.reshape(-1, 2)[self.problem.quads]                   # (E, 4, 2)
        return np.eye(2) + np.matmul(ue.transpose(0, 2, 1)[:, None], self.grad0)

    def evaluate(self, x: np.ndarray, tangent: bool = True):
        """Element residuals ``(E, 8)``, tangents ``(E, 8, 8)`` (or None), min det F ``(E,)``."""
        p = self.p
        F = self.deformation_gradient(x)
        detF = F[..., 0, 0] * F[..., 1, 1] - F[..., 0, 1] * F[..., 1, 0]
        if np.any(detF <= 0.0):                  # inverted: the energy is undefined there
            return None, None, detF.min(axis=1)
        if not tangent:
            S = stress(F, p.A10, self.A20, p.A30, p.kappa)
        else:
            S, D = stress_and_tangent(F, p.A10, self.A20, p.A30, p.kappa)
        P = np.matmul(F, S)                                         # first Piola-Kirchhoff
        Re = (np.matmul(self.grad0, np.swapaxes(P, -1, -2)) * self.wdet[..., None, None]).sum(axis=1)
        Re = Re.reshape(-1, 8)
        if not tangent:
            return Re, None, detF.min(axis=1)
        g = self.grad0
        BL = np.empty(g.shape[:2] + (3, 8), dtype=F.dtype)
        for i in range(2):                  # dofs 2a + i
            BL[..., 0, i::2] = F[..., i, 0, None] * g[..., 0]
            BL[..., 1, i::2] = F[..., i, 1, None] * g[..., 1]
            BL[..., 2, i::2] = F[..., i, 0, None] * g[..., 1] + F[..., i, 1, None] * g[..., 0]
        Ke = weighted_gram(BL, D @ BL, self.wdet)
        Gab = weighted_gram(g.transpose(0, 1, 3, 2), S @ g.transpose(0, 1, 3, 2), self.wdet)
        Ke[:, 0::2, 0::2] += Gab
        Ke[:, 1::2, 1::2] += Gab
        return Re, Ke, detF.min(axis=1)


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

    def move(self, problem: MotionProblem, prescribed: np.ndarray, progress=None) -> MoveResult:
        target, t0 = self._start(problem, prescribed)
        report = MoveReport(mover=self.name)
        p = self.params
        blend = self.blend(problem)
        eqs = Equations(YeohKernel(problem, p), blend, target)
        solver = self._solver(problem)
        x = np.zeros_like(target)
        state = eqs.kernel.evaluate(x)[:2]              # element residuals and tangents at x
        load, step = 0.0, 1.0 / p.increments
        while load < 1.0 - 1e-14:
            step = min(step, 1.0 - load)
            x_new, state_new, history, why = self._increment(eqs, solver, x, state, load, load + step,
                                                             report)
            report.residual_history.append(history)
            if x_new is None:
                report.cutbacks += 1
                step *= 0.5
                log.info("yeoh: increment at load %.4g failed (%s); cut to %.3g", load, why, step)
                if step < p.min_increment or report.cutbacks > p.max_cutbacks:
                    self._fail(report, problem, x, f"no convergence at load {load:.4g} after "
                               f"{report.cutbacks} cutbacks (last: {why})", t0)
                continue
            x, state, load = x_new, state_new, load + step
            report.increments += 1
            record = quality_record(problem, x.reshape(-1, 2), load)
            report.quality.append(record)
            if progress:
                progress(report.increments, p.increments, record)
            if len(history) <= 4:                # easy increment: take a longer next one
                step *= 1.5
        return self._finish(report, problem, x, t0, solver, blend=blend, target=target)

    def _line_search(self, eqs: Equations, x, dx, r, norm, load):
        """Step length along ``dx``: returns (x_new, Re, Ke or None) or None.

        ``g(alpha) = dx . D(x + alpha dx)`` is the slope of the energy along the
        step (without a blend); ``g(0) = dx . r < 0``. Accept the full step when
        the slope has dropped to a tenth; otherwise try the secant root
        ``g0 / (g0 - g(1))`` (clipped to [0.1, 4]) once, then halve. An accepted
        step must reduce ``|D|`` and invert no element.
        """
        kernel = eqs.kernel

        def trial(alpha, tangent):
            xt = x + alpha * dx
            Re_t, Ke_t, det_t = kernel.evaluate(xt, tangent)
            if Re_t is None or not self._valid(kernel, xt, det_t):
                return xt, None, None, None, None
            rt = eqs.residual(Re_t, xt, load)
            return xt, Re_t, Ke_t, float(dx @ rt), float(np.linalg.norm(rt))

        g0 = float(dx @ r)
        alphas = [1.0]
        xt, Re_t, Ke_t, g1, n1 = trial(1.0, True)
        if g1 is not None and n1 < norm and (g0 >= 0 or abs(g1) <= 0.1 * abs(g0)):
            return xt, Re_t, Ke_t
        if g1 is not None and g0 < 0 and g1 != g0:
            alphas.append(float(np.clip(g0 / (g0 - g1), 0.1, 4.0)))
        alphas += [0.5 ** k for k in range(1, 7)]
        best = (xt, Re_t, Ke_t, n1) if g1 is not None and n1 < (1 - 1e-4) * norm else None
        for alpha in alphas[1:]:
            xa, Re_a, _, ga, na = trial(alpha, False)
            if ga is not None and na < (1 - 1e-4 * min(alpha, 1.0)) * norm and (best is None or na < best[3]):
                return xa, Re_a, None
            if best is not None:
                return best[:3]
        return None if best is None else best[:3]

    def _valid(self, kernel: YeohKernel, x: np.ndarray, det_min: np.ndarray) -> bool:
        if np.any(det_min <= 0.0):
            return False
        P = kernel.problem
        return not np.any(quality.inverted(P.points + x.reshape(-1, 2), P.quads))

    def _increment(self, eqs: Equations, solver: RecyclingSolver, x0: np.ndarray, state0,
                   load0: float, load1: float, report: MoveReport):
        """Newton solve from the converged ``x0`` (element residuals and tangents
        ``state0``) at ``load0`` to ``load1``; returns (x or None, its (Re, Ke),
        |D_free| history, reason)."""
        p, bc = self.params, eqs.bc
        Re, Ke = state0
        boundary_step = (load1 - load0) * eqs.target
        jump = eqs.jump(Ke, boundary_step)
        r0 = eqs.residual(Re, x0, load1)
        rhs = -(r0 + jump)
        rhs[bc.fixed] = boundary_step[bc.fixed]
        delta = solver.solve(eqs.matrix(Ke), rhs, rtol=1e-3)   # tangent predictor (loose)
        delta[bc.fixed] = boundary_step[bc.fixed]
        x = x0 + delta
        report.linear_solves += 1
        R_fixed = assemble_vector(eqs.dofs, Re, x0.size)[bc.fixed]
        scale = max(np.linalg.norm(jump), np.linalg.norm(r0), np.linalg.norm(R_fixed), 1e-300)
        history: list[float] = []
        Re, Ke, det_min = eqs.kernel.evaluate(x)
        if Re is None or not self._valid(eqs.kernel, x, det_min):
            return None, None, history, "predictor inverts an element"
        for it in range(p.max_newton + 1):
            r = eqs.residual(Re, x, load1)
            norm = float(np.linalg.norm(r))
            history.append(norm)
            log.info("yeoh Newton %d: |R| = %.3e", it, norm)
            if not np.isfinite(norm):
                return None, None, history, "non-finite residual"
            forces = np.linalg.norm(assemble_vector(eqs.dofs, Re, x.size))   # reactions, and the
            target = max(p.newton_tol * max(scale, forces),  # blended rows' balancing forces,
                         ROUND_OFF * np.sqrt(x.size) * forces)  # but never below round-off
            if norm <= target:
                return x, (Re, Ke), history, ""
            if it == p.max_newton:
                return None, None, history, f"{p.max_newton} Newton iterations"
            dx = solver.solve(eqs.matrix(Ke), -r, rtol=forcing_term(history, target))
            dx[bc.fixed] = 0.0
            report.linear_solves += 1
            report.newton_iterations += 1
            found = self._line_search(eqs, x, dx, r, norm, load1)
            if found is None:
                return None, None, history, "line search found no decrease"
            trial, Re_t, Ke_t = found
            if Ke_t is None:                                  # not the full step: tangent now
                Re_t, Ke_t, _ = eqs.kernel.evaluate(trial)
            x, Re, Ke = trial, Re_t, Ke_t
        return None, None, history, "unreachable"
