"""Linear-elastic mover, optionally Jacobian-stiffened (Stein, Tezduyar & Benney 2003).

The mesh is a plane-strain elastic body (unit modulus; only Poisson's ratio
matters with prescribed displacements only). Element stiffness
``K_e = f_e sum_g w_g B^T D B det J_g^(1 - chi)``, ``f_e`` the layered
stiffening factor. With one increment the motion solves ``K x = 0`` on the
reference mesh (``x = u`` on the prescribed nodes); with more, each
increment solves on the updated mesh (see :mod:`movers.incremental`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from movers.base import Mover, MoveReport, MoveResult
from movers.problem import MotionProblem
from movers.increment_solvers import increment_solver
from movers.increment_kernel import IncrementKernel
from movers.incremental import MoveRecord, increments_jvp, increments_vjp, run_increments
from tofsi.core.config import option
from tofsi.core.errors import NumericalError
from tofsi.fem.elasticity import element_stiffness, lame


@dataclass(frozen=True)
class LinearParams:
    renamed_keys = {"linear_solver": "tangent_solver"}     # the old name, accepted with a warning
    poisson_ratio: float = option(0.3, gt=-1.0, lt=0.5, doc="Poisson's ratio of the mesh")
    chi: float = option(0.0, ge=0, le=10, doc="Jacobian stiffening power (0: none)")
    increments: int = option(1, ge=1, le=100_000, doc="increments on the updated mesh")
    tangent_solver: str = option("direct", choices=("direct", "amg"),
                                 doc="the tangent's linear solver: sparse LU or AMG-CG")
    linear_tol: float = option(1e-10, gt=0, lt=1e-3, doc="relative tolerance of recycled iterative solves")


class LinearElasticMover(Mover):
    """Linear elasticity, one solve or increments on the updated mesh."""

    name = "linear"
    Params = LinearParams
    warm_starts = True          # ``solver``: the factorizations of earlier moves at the design

    def element_matrices(self) -> IncrementKernel:
        """Unscaled element stiffness of the current corners (complex-safe; the shape derivative
        of its forces by complex step)."""
        lam, mu = lame(1.0, self.params.poisson_ratio)
        chi = self.params.chi
        return IncrementKernel(lambda Xe: element_stiffness(Xe, lam, mu, chi=chi), key=(self.name, lam, mu, chi))

    @property
    def path_dependent(self) -> bool:
        return self.params.increments > 1

    def element_residual(self, problem: MotionProblem, x: np.ndarray, factors, tangent: bool = True):
        """One increment on the reference mesh is linear: ``R_e = f_e K0_e x_e``."""
        K = self.element_matrices()(problem.points[problem.quads]) * np.asarray(factors)[:, None, None]
        return np.einsum("eab,eb->ea", K, np.asarray(x).reshape(-1)[problem.dofs]), (K if tangent else None)

    def reference_matrices(self, problem: MotionProblem) -> np.ndarray:
        return self.element_matrices()(problem.points[problem.quads])

    def move(self, problem: MotionProblem, prescribed: np.ndarray, progress=None, initial=None,
             solver=None) -> MoveResult:
        """The motion (in increments); ``solver``: :meth:`increment_solvers` of ``problem`` (earlier
        moves' factorizations, preconditioning this one's solves; any other is not used, nor is
        ``initial``)."""
        target, t0 = self._start(problem, prescribed)
        report = MoveReport(mover=self.name)
        solver = increment_solver(self._solver(problem), solver)
        blend = self.blend(problem)
        record = MoveRecord()
        try:
            x, states = run_increments(problem, target, self.params.increments,
                                       self.element_matrices(), solver, report, progress, blend, record)
        except NumericalError as err:
            self.raise_failure(report, problem, None, str(err), t0)
        return self._finish(report, problem, x, t0, solver, trajectory=states, blend=blend,
                            target=target, record=record)

    def jvp(self, problem: MotionProblem, result: MoveResult, t_dot: np.ndarray) -> np.ndarray:
        """Tangent sweep through the increments (with one: a residual mover's, see ``residual``)."""
        if not self.path_dependent:
            return super().jvp(problem, result, t_dot)
        return increments_jvp(problem, result, self.element_matrices(), t_dot).reshape(-1, 2)

    def vjp(self, problem: MotionProblem, result: MoveResult, xbar: np.ndarray):
        """Reverse sweep through the increments (with one: the adjoint of ``K x = 0, x_p = u_p``)."""
        if not self.path_dependent:
            return super().vjp(problem, result, xbar)
        t_bar, f_bar, s_bar = increments_vjp(problem, result, self.element_matrices(), xbar)
        return t_bar.reshape(-1, 2), f_bar, s_bar
