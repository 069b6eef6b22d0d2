"""Spring-analogy mover (Farhat et al. 1998) on triangulated quads.

Each quad is split along diagonal 1-3, 2-4, both, or *selectively*: two
trial increments, one with every quad split 1-3 and one with 2-4, then each
quad keeps the diagonal whose quad had the higher skewness (skewness is
always measured on the quads). The motion is applied in increments on the
updated mesh (see :mod:`movers.incremental`), because the torsional springs
linearize the angle change (sin d(theta) ~ d(theta)): each at its start as
the paper does (``scheme = "euler"``, the path errs like 1/N), or at its
midpoint extrapolated from the increment before (``scheme = "midpoint"``,
like 1/N^2 for the same one solve per increment; the first increment, with
nothing before it, at its start: ``first_increment`` makes it smaller).

Layered stiffening multiplies both the lineal and the torsional stiffness of
a quad's triangles by the quad's factor.

The selective choice depends on the motion, so as a function of the design
the map is piecewise smooth: its vector-Jacobian product holds the choice
fixed (exact between switches). Optimizations that need a smooth map use a
fixed triangulation.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from movers.base import Mover, MoveReport, MoveResult
from movers.problem import MotionProblem
from movers.increment_solvers import increment_solver
from movers.increment_kernel import IncrementKernel, schedule
from movers.incremental import MoveRecord, increment, increments_jvp, increments_vjp, run_increments
from movers.spring_kernel import DIAGONALS, TriangleSplit, quad_force_derivative, quad_stiffness
from tofsi.mesh import quality
from tofsi.core.config import option
from tofsi.core.errors import NumericalError
from tofsi.core.kept import Kept, input_key

CHOICES = ("1-3", "2-4", "both", "selective")
SCHEMES = ("euler", "midpoint")
EXTRAPOLATION = {"euler": 0.0, "midpoint": 0.5}     # movers.increment_kernel.IncrementKernel's


@dataclass(frozen=True)
class SpringParams:
    renamed_keys = {"linear_solver": "tangent_solver"}     # the old name, accepted with a warning
    diagonals: str = option("selective", choices=CHOICES, doc="quad triangulation")
    increments: int = option(30, ge=1, le=100_000, doc="equal increments of the motion")
    scheme: str = option("euler", choices=SCHEMES,
                         doc="each increment's stiffness: at its start (euler, the paper's) or at its "
                             "midpoint extrapolated from the increment before (midpoint, second order)")
    first_increment: float = option(0.0, ge=0, lt=1,
                                    doc="the first increment's share of the motion, the others equal "
                                        "(0: all equal; one increment takes it all); with scheme "
                                        "midpoint the first increment alone is first order, so a "
                                        "small one (0.1) keeps the path second order")
    torsion_scale: float = option(1.0, gt=0, doc="torsional stiffness scale TSC")
    tangent_solver: str = option("direct", choices=("direct", "amg"),
                                 doc="the tangent's linear solver: sparse LU or AMG-CG")
    linear_tol: float = option(1e-10, gt=0, lt=1e-3, doc="relative tolerance of recycled iterative solves")


class SpringMover(Mover):
    """Lineal + torsional springs, solved in increments on the updated mesh."""

    name = "spring"
    Params = SpringParams
    warm_starts = True          # ``solver``: the factorizations of earlier moves at the design

    def __init__(self, params):
        super().__init__(params)
        self.kept_split = Kept()        # the last diagonal codes' TriangleSplit (built on first use)

    def element_matrices(self, codes: np.ndarray) -> IncrementKernel:
        """Unscaled quad matrices for the diagonal codes (complex-safe) and their forces' shape
        derivative (closed form)."""
        tsc = self.params.torsion_scale
        split = functools.cache(lambda: self.kept_split.get(input_key(codes), lambda: TriangleSplit(codes)))
        return IncrementKernel(lambda Xe: quad_stiffness(Xe, split(), tsc),
                               lambda Xe, v: quad_force_derivative(Xe, v, split(), tsc),
                               EXTRAPOLATION[self.params.scheme], key=input_key(self.name, codes, tsc),
                               first=self.params.first_increment)

    @property
    def path_dependent(self) -> bool:
        """Several increments, or selective diagonals (chosen from the motion itself)."""
        return self.params.increments > 1 or self.params.diagonals == "selective"

    @property
    def kinks(self) -> str:
        if self.params.diagonals != "selective":
            return ""
        return ("selective diagonals switch as the motion or the stiffening changes and a gradient "
                "holds them fixed; mover.spring.diagonals = 'both' gives a smooth map")

    def element_residual(self, problem: MotionProblem, x: np.ndarray, factors, tangent: bool = True):
        """One increment with fixed diagonals is linear: ``R_e = f_e K0_e(X) x_e``."""
        if self.path_dependent:
            return super().element_residual(problem, x, factors, tangent)
        codes = np.full(len(problem.quads), DIAGONALS.index(self.params.diagonals))
        K = self.element_matrices(codes)(problem.points[problem.quads]) * np.asarray(factors)[:, None, None]
        return np.einsum("eab,eb->ea", K, np.asarray(x).reshape(-1)[problem.dofs]), (K if tangent else None)

    def reference_matrices(self, problem: MotionProblem) -> np.ndarray:
        """Both-diagonal matrices of the reference mesh (the blend scale must not depend
        on the diagonal choice)."""
        return quad_stiffness(problem.points[problem.quads], np.full(len(problem.quads), 2),
                              self.params.torsion_scale)

    def choose_diagonals(self, problem: MotionProblem, target: np.ndarray, solver,
                         report: MoveReport, blend=None) -> np.ndarray:
        """Per-quad diagonal codes from two trial increments with opposite diagonals."""
        x0 = np.zeros_like(target)
        skew = []
        for code in (0, 1):
            codes = np.full(len(problem.quads), code)
            kernel = self.element_matrices(codes)
            step = schedule(kernel, self.params.increments)[0][0] * target       # the first increment's
            dx = increment(problem, kernel, x0, step, solver, report, blend=blend)
            skew.append(quality.skewness(problem.points + dx.reshape(-1, 2), problem.quads))
        return np.where(skew[1] > skew[0], 1, 0)

    def move(self, problem: MotionProblem, prescribed: np.ndarray, progress=None, initial=None,
             solver=None) -> MoveResult:
        """The motion in increments; ``solver``: :meth:`increment_solvers` of ``problem`` (earlier
        moves' factorizations, preconditioning this one's solves; any other is not used, nor is
        ``initial``)."""
        target, t0 = self._start(problem, prescribed)
        report = MoveReport(mover=self.name)
        recycling = self._solver(problem)
        solver = increment_solver(recycling, solver)
        blend = self.blend(problem)
        choice = self.params.diagonals
        if choice == "selective":
            codes = self.choose_diagonals(problem, target, recycling, report, blend)
        else:
            codes = np.full(len(problem.quads), DIAGONALS.index(choice))
        record = MoveRecord()
        try:
            x, states = run_increments(problem, target, self.params.increments,
                                       self.element_matrices(codes), solver, report, progress, blend, record)
        except NumericalError as err:
            self.raise_failure(report, problem, None, str(err), t0)
        result = self._finish(report, problem, x, t0, solver, trajectory=states, blend=blend,
                              target=target, record=record)
        result.cell_data["diagonal"] = codes
        return result

    def jvp(self, problem: MotionProblem, result: MoveResult, t_dot: np.ndarray) -> np.ndarray:
        """Tangent sweep through the increments (the diagonal choice is held fixed)."""
        kernel = self.element_matrices(result.cell_data["diagonal"])
        return increments_jvp(problem, result, kernel, t_dot).reshape(-1, 2)

    def vjp(self, problem: MotionProblem, result: MoveResult, xbar: np.ndarray):
        """Reverse sweep through the increments (the diagonal choice is held fixed)."""
        t_bar, f_bar, s_bar = increments_vjp(problem, result,
                                             self.element_matrices(result.cell_data["diagonal"]), xbar)
        return t_bar.reshape(-1, 2), f_bar, s_bar
