"""The factorizations of a mover's increments, kept across its moves at one design.

A mover in increments on the updated mesh (:mod:`movers.incremental`) moves the
mesh once per Newton iterate and line-search trial of a coupled solve, each
time for a nearby structure motion, so increment ``k``'s system differs little
from increment ``k``'s of the move before. :class:`IncrementSolvers` keeps, per
increment, the sparse LU factors of a nearby system; a move's increments are
solved by FGMRES preconditioned with them (:class:`MoveSolver`), and the store
of a move's derivatives (:class:`movers.incremental.IncrementDerivatives`)
gives the factors it makes back. The caller keys it by the densities
(:meth:`tofsi.physics.mesh_motion.MeshMotion.move`), so a new design starts
afresh.
"""

from __future__ import annotations

import numpy as np

from movers.problem import MotionProblem
from tofsi.core.kept import Kept
from tofsi.linalg import LinearAlgebra
from tofsi.linalg.recycling import flexible_gmres

KEPT_FACTORS_TOL_RATIO = 1e-3
"""Kept factors solve to this fraction of the mover's ``linear_tol`` (see :class:`IncrementSolvers`)."""


class IncrementSolvers:
    """Exact factorizations (sparse LU) of the increments' systems, kept across the moves at one
    design (the caller keys it by the densities, :meth:`tofsi.physics.mesh_motion.MeshMotion.move`):
    a Newton's iterates and line-search trials move the mesh for nearby structure motions, so
    increment ``k``'s system differs little from increment ``k``'s of the move before.

    A move solves increment ``k`` by flexible GMRES (to ``rtol`` relative to the right-hand side)
    preconditioned by the factors kept for increment ``k`` -- made at increment ``k`` of an
    earlier move, or by the store of an earlier move's derivatives
    (:class:`~movers.incremental.IncrementDerivatives`, which gives its factors back here) --,
    else by the factors the move used last (an earlier increment's, as a recycling solver
    would) for at most ``refresh_after`` iterations, from the change increment ``k`` made in the
    latest move (else the increment before's). Where GMRES needs more than ``max_iter``
    iterations (``refresh_after`` on an earlier increment's factors) the system is factorized;
    where it needed more than ``refresh_after`` the factors used are not used for that increment
    again, and once an earlier increment's factors failed, the move factorizes its increments
    without factors of their own (increments far apart, as the large scene's 4: 14-18 iterations
    each on their neighbour's factors, where a factorization costs about 8 and serves the store
    of the move's derivatives, which would else make it). Factors made at a move's own system
    serve its store. The system the factors kept for increment ``k`` were made at
    (``made_at``, held here: identity cannot match a recycled object) is solved by them
    directly: every move's first increment, whose matrices and system at the reference mesh
    ``reference`` keeps (:func:`movers.incremental.stiffness_and_system`, keyed by all their
    inputs). Results never depend on timing, only on the moves made at
    the design (iteration counts). Which factors a move uses depends on the moves before it, so
    its solver error, unlike a fresh recycling solver's, is not a smooth function of the motion:
    finite differences across moves see it (at ``rtol = 1e-10`` a remainder floor of 1e-11 in
    ``tofsi check-gradients``' ``D_u`` and ``D_rho``), hence ``rtol`` is a thousandth of the
    mover's ``linear_tol`` (:func:`solvers_for`)."""

    exact = True

    def __init__(self, factorize, rtol: float = 1e-10, max_iter: int = 20, refresh_after: int = 6):
        self.factorize, self.rtol = factorize, rtol
        self.max_iter, self.refresh_after = max_iter, refresh_after
        self.factors: dict[int, object] = {}          # increment -> factors of a system near its own
        self.steps: dict[int, np.ndarray] = {}        # increment -> its change in the latest move
        self.made_at: dict[int, object] = {}          # increment -> the system its factors were made at here
        self.reference = Kept()     # the first increment's (K0, A) at the reference mesh (movers.incremental)

    def move(self) -> "MoveSolver":
        """The solver of one move (its own counts and its latest factors)."""
        return MoveSolver(self)

    def keep(self, factors) -> None:
        """Take the factors a store made (per increment, exact at its move's systems)."""
        for k, f in enumerate(factors):
            if f is not None and f is not self.factors.get(k):
                self.factors[k] = f
                self.made_at.pop(k, None)


class MoveSolver:
    """One move's use of :class:`IncrementSolvers`: ``solve_increment`` and the move's counts."""

    exact = True

    def __init__(self, bank: IncrementSolvers):
        self.bank, self.factorize = bank, bank.factorize
        self.factorizations = self.krylov_iterations = 0
        self.latest = None                             # the factors the move used last
        self.neighbours = True                         # an earlier increment's factors may serve

    def keep(self, factors) -> None:
        self.bank.keep(factors)

    def solve_increment(self, k: int, A, b: np.ndarray, guess=None):
        """``(A^-1 b, factors made at A or None)`` for increment ``k``'s system ``A`` (a system the
        bank's factors were made at, the kept first increment's, by them directly)."""
        bank = self.bank
        own = bank.factors.get(k)
        if own is not None and bank.made_at.get(k) is A:     # made at this very system (the kept first increment's)
            bank.steps[k] = x = own.solve(b)
            self.latest = own
            return x, own
        preconditioner = own if own is not None else self.latest if self.neighbours else None
        before = bank.steps.get(k)
        if before is not None and before.shape == b.shape:
            guess = before                            # the latest move's: nearer than the increment before
        if preconditioner is not None and preconditioner.shape == A.shape:
            goal = bank.rtol * float(np.linalg.norm(b))
            cap = bank.max_iter if preconditioner is own else bank.refresh_after
            x, its = flexible_gmres(A, b, preconditioner.preconditioner(), goal, cap, cap, guess)
            self.krylov_iterations += its
            if np.all(np.isfinite(x)) and np.linalg.norm(b - A @ x) <= 1.01 * goal:
                if its > bank.refresh_after:          # gone stale: factorize the next time instead
                    del bank.factors[k]
                    bank.made_at.pop(k, None)
                    self.latest = None
                else:
                    self.latest = preconditioner
                bank.steps[k] = x
                return x, None
            if preconditioner is not own:             # increments too far apart for their neighbours'
                self.neighbours = False
        made = bank.factorize(A)
        self.factorizations += 1
        bank.factors[k] = self.latest = made
        bank.made_at[k] = A
        bank.steps[k] = x = made.solve(b)
        return x, made


def solvers_for(problem: MotionProblem, params) -> IncrementSolvers | None:
    """The :class:`IncrementSolvers` of a mover in increments (``params``: its ``tangent_solver``
    and ``linear_tol``) on ``problem``: sparse LU on the problem's backend; None where its
    tangent solver is iterative (AMG, or the iterative path)."""
    la = problem.linear_algebra or LinearAlgebra.default()
    if la.iterative or getattr(params, "tangent_solver", "direct") == "amg":
        return None
    rtol = KEPT_FACTORS_TOL_RATIO * getattr(params, "linear_tol", 1e-10)
    return IncrementSolvers(lambda A: la.direct(A, perm=problem.ordering), rtol=rtol)


def increment_solver(solver, bank):
    """A move's solver: its share of ``bank`` where that is an :class:`IncrementSolvers` (exact
    factorizations kept across the moves at one design), else the recycling ``solver``."""
    return bank.move() if isinstance(bank, IncrementSolvers) else solver
