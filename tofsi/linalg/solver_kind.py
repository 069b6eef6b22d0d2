"""What a :class:`~tofsi.linalg.RecyclingSolver` asks of the factorization or hierarchy it keeps."""

from __future__ import annotations

import math

GMRES_RESTART = 50          # restart length of GMRES preconditioned by an AMG cycle


class SolverKind:
    """The base of every solver a :class:`~tofsi.linalg.RecyclingSolver` keeps (sparse LU, an AMG
    hierarchy, a block sweep): its kind, and what it does not have unless it says so.

    exact : sparse LU (its factors precondition GMRES; a stale solve refactorizes), else an
        iterative preconditioner (every solve a Krylov solve by one cycle or sweep of it)
    symmetric : CG (a symmetric positive definite system and preconditioner), else GMRES
    follows_matrix : ``preconditioner(transpose, matrix=A)`` takes the current matrix (a block
        sweep applies its couplings), else ``preconditioner(transpose)``
    linear_preconditioner : one fixed linear operator (GMRES(m)), else flexible GMRES
    restart : GMRES(m)'s m
    own_krylov : ``solve_with(A, b, transpose)`` solves with the solver's own Krylov norm
    refactor_iterations : the Krylov iterations that refactorizing its cheap part costs
        (:meth:`refactor_small_blocks`; infinite: it has none)
    """

    exact = False
    symmetric = False
    follows_matrix = False
    linear_preconditioner = False
    restart = GMRES_RESTART
    own_krylov = False
    refactor_iterations = math.inf

    def refactor_small_blocks(self, A) -> list[int] | None:
        """Factorize again at ``A`` the preconditioner's cheap part; the blocks refactorized, or
        None: it has none (see :meth:`tofsi.linalg.BlockGaussSeidel.refactor_small_blocks`)."""
        return None
