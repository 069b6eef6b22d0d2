"""Yeoh hyperelastic mover: total Lagrangian, Newton from one load step or a nearby solution.

Unknown: the mesh displacement ``x`` (2n). Residual (internal forces of the
reference mesh, 2x2 Gauss points):

    R_a,i(x) = sum_g w_g det J0_g P_iJ dN_a/dX_J,   P = F S,   F = I + grad0 x,

with ``S`` from :mod:`movers.yeoh_material` (``A20`` times the quad's
stiffening factor). The tangent is the consistent one, ``dR/dx`` through the
first elasticity tensor ``A = dP/dF``; residual and tangent come from one
pass of :class:`movers.yeoh_kernel.YeohKernel`.

The prescribed motion is applied as ``lambda u`` with ``lambda`` stepping from
0 to 1, in one step unless ``increments`` says otherwise, by
:class:`movers.newton.LoadStepNewton` on :class:`SerialOperators` (the mover by
slabs runs the same Newton on its distributed operators). Each step starts
with a tangent predictor (the boundary step and the free nodes' linear
response), then Newton corrections with a
line search on the energy's slope along the step, ``g(alpha) = dx . R(x + alpha dx)``
(Crisfield's secant search: the step may be shortened or, when the energy is
nearly quartic as with a large A20, extended up to 4x), falling back to
halving; every trial refuses an element whose ``det F`` or corner Jacobian
is not positive, and an accepted step must reduce ``|R_free|``. A step that fails
(inversion, no decrease, iteration limit) is cut in half; the mover stops
with a diagnostic when the step falls below ``min_increment``, after
``max_cutbacks`` cuts, or once one element has blocked 8 cut steps (the mesh
folds there: :data:`movers.newton.BLOCKED_CUTBACKS`). A move given ``initial``, the solution of a nearby
motion (the previous design's, or the previous coupling sweep's), makes one
step from there straight to the full motion, and falls back to load steps
from zero when that fails. Tangent systems are solved by a
:class:`~tofsi.linalg.RecyclingSolver` (factorize, or build an AMG
hierarchy, rarely; precondition the Krylov solves of the tangents in between),
which a move may inherit from an earlier one (``solver``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from movers.base import Mover, MoveReport, MoveResult, element_apply, quality_record
from movers.problem import MotionProblem
from movers.failure import broken_element
from movers.incremental import system
from movers.newton import LoadStepNewton, NewtonSettings
from movers.yeoh_kernel import YeohKernel
from tofsi.mesh import quality
from tofsi.core.config import option
from tofsi.core.errors import NumericalError
from tofsi.fem.assembly import assemble_vector
from tofsi.linalg import RecyclingSolver


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


class SerialOperators:
    """The Yeoh mover's equations at load ``lambda`` on the whole mesh, as
    :class:`movers.newton.LoadStepNewton` reads them: ``D(x) = 0``.

    Free rows ``W R(x) + S_c (x - lambda t)`` (``W = 1``, ``S_c = 0`` without a
    blend), fixed rows ``x_p = lambda t_p``; the Jacobian is ``W K + S_c`` with
    identity rows on the fixed dofs, solved by ``solver`` (a
    :class:`~tofsi.linalg.RecyclingSolver`). A state is the element residuals and
    tangents ``(Re, Ke)`` at ``x``; an element is valid where ``det F > 0`` at its
    Gauss points and no corner Jacobian is non-positive.
    """

    def __init__(self, kernel: YeohKernel, blend, target: np.ndarray, solver: RecyclingSolver,
                 t0: float, progress=None):
        self.kernel, self.blend, self.target, self.solver = kernel, blend, target, solver
        self.t0, self.progress = t0, progress
        self.problem = kernel.problem
        self.bc, self.dofs = kernel.problem.bc, kernel.problem.dofs
        self.fixed = self.bc.fixed

    def evaluate(self, x: np.ndarray, tangent: bool = True):
        Re, Ke, det_min = self.kernel.evaluate(x, tangent)
        if Re is None or np.any(det_min <= 0.0):
            return None
        if np.any(quality.inverted(self.problem.points + x.reshape(-1, 2), self.problem.quads)):
            return None
        return Re, Ke

    def forces(self, state) -> np.ndarray:
        return assemble_vector(self.dofs, state[0], self.target.size)

    def residual(self, state, x: np.ndarray, load: float) -> np.ndarray:
        r = assemble_vector(self.dofs, state[0], x.size)
        if self.blend is not None:
            r = self.blend.residual(r, x, load * self.target)
        return self.bc.homogenize(r)

    def jump(self, state, boundary_step: np.ndarray) -> np.ndarray:
        """Free-row response ``W K_fp d_p`` to moving the fixed dofs by ``d_p``."""
        d = np.zeros_like(boundary_step)
        d[self.bc.fixed] = boundary_step[self.bc.fixed]
        r = element_apply(state[1], d, self.dofs)
        return self.bc.homogenize(r if self.blend is None else self.blend.weighted(r))

    def solve(self, state, rhs: np.ndarray, rtol: float) -> np.ndarray:
        return self.solver.solve(system(self.bc, state[1], self.dofs, self.blend), rhs, rtol=rtol)

    def nearer(self, x0: np.ndarray) -> bool:
        """True when ``x0`` is nearer than zero to the full motion on the dofs the motion
        prescribes (the fixed ones, and the blended ones)."""
        carried = self.bc.is_fixed if self.blend is None else self.bc.is_fixed | (self.blend.diag > 0)
        return bool(np.linalg.norm((self.target - x0)[carried]) < np.linalg.norm(self.target[carried]))

    def broken(self, x: np.ndarray) -> dict | None:
        return broken_element(self.problem, x, self.kernel.evaluate(x, tangent=False)[2])

    def record(self, report: MoveReport, x: np.ndarray, load: float, planned: int) -> None:
        report.increments += 1
        record = quality_record(self.problem, x.reshape(-1, 2), load)
        report.quality.append(record)
        if self.progress:
            self.progress(report.increments, planned, record)

    def fail(self, report: MoveReport, x, message: str, load: float, broken) -> None:
        Mover.raise_failure(report, self.problem, x, message, self.t0, load, broken)


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
    takes_tolerance = True      # move() takes ``tol``: a looser Newton tolerance (a coupled sweep's start)

    def move(self, problem: MotionProblem, prescribed: np.ndarray, progress=None,
             initial: np.ndarray | None = None, solver: RecyclingSolver | None = None,
             tol: float | None = None) -> MoveResult:
        """Displacement with the fixed nodes at ``prescribed``.

        initial : ``(n, 2)`` a mesh displacement for a nearby motion (e.g. the
            previous design's or coupling sweep's) to start from: one Newton solve
            goes straight to the full motion (no load steps) when its prescribed
            values are nearer to the target than zero is; when that fails, and
            without ``initial``, the motion is applied in load steps from zero.
        solver : the :class:`~tofsi.linalg.RecyclingSolver` of an earlier move of
            the same mesh, whose factorization (or hierarchy) preconditions this
            move's systems until it goes stale.
        tol : a Newton tolerance looser than ``newton_tol`` (``|D_free|`` relative to the
            force scale, :meth:`movers.newton.LoadStepNewton.tolerance`), for a move that
            only starts a coupled Newton (the monolithic solve's starting sweep).
        The result does not depend on ``initial`` or ``solver`` (to the tolerance).
        """
        target, t0 = self._start(problem, prescribed)
        report = MoveReport(mover=self.name)
        blend = self.blend(problem)
        solver = self._solver(problem) if solver is None else solver
        counts = solver.factorizations, solver.krylov_iterations
        ops = SerialOperators(YeohKernel(problem, self.params), blend, target, solver, t0, progress)
        settings = NewtonSettings.of(self.params)
        if tol is not None:
            settings = replace(settings, newton_tol=max(tol, settings.newton_tol))
        x = LoadStepNewton(ops, settings, report, "yeoh").move(initial)
        result = self._finish(report, problem, x, t0, solver, blend=blend, target=target)
        report.factorizations -= counts[0]               # this move's own
        report.krylov_iterations -= counts[1]
        return result
