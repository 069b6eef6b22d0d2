"""The linear algebra a model uses: its sparse direct backend and threads, as one record.

Every model (:class:`tofsi.coupling.coupled.CoupledModel`, a mesh-motion study) owns a
:class:`LinearAlgebra` built from its scene's ``[solver]`` table and hands it
to the physics it builds; each factorization is made on that backend with
those threads. Nothing process-wide changes when a model is built, so two
models with different ``[solver]`` tables can live side by side. The
environment variables ``TOFSI_LINEAR_SOLVER``, ``TOFSI_THREADS`` and
``TOFSI_BLAS_THREADS`` win over the scene (to run a benchmark or the tests on
another backend), as documented in ``docs/parallel.md``.
"""

from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass

from tofsi.linalg.iterative import TRANSPOSE_TOL

log = logging.getLogger(__name__)
ITERATIVE = "iterative"          # the value of solver.linear_solver that selects the iterative path


def environment_int(name: str, value: int) -> int:
    """``value``, unless the environment variable ``name`` holds a whole number."""
    text = os.environ.get(name, "").strip()
    if not text:
        return value
    try:
        return max(int(text), 0)
    except ValueError:
        log.warning("ignoring %s=%r (not an integer)", name, text)
        return value


def solver_threads(requested: int = 0) -> int:
    """Threads for the sparse direct backend (0: one per core; ``TOFSI_THREADS`` wins)."""
    n = environment_int("TOFSI_THREADS", requested)
    return n if n > 0 else (os.cpu_count() or 1)


@dataclass(frozen=True)
class LinearAlgebra:
    """backend : a concrete backend name (``superlu``, ``pardiso``, ``petsc``); threads :
    threads of the direct backend (PARDISO's; 0: leave the backend as it is); blas_threads :
    OpenBLAS threads while the model computes (0: as the environment says); iterative : the
    iterative path (``linear_solver = "iterative"``): the flow by block-preconditioned FGMRES,
    the structure and the movers by AMG-CG; ``backend`` is then the direct backend of what
    stays direct (the coupled block systems' diagonal blocks); adjoint_tol : the iterative
    path's tolerance of the flow's transposed solves (``solver.adjoint_tol``)."""

    backend: str = "superlu"
    threads: int = 0
    blas_threads: int = 0
    iterative: bool = False
    adjoint_tol: float = TRANSPOSE_TOL

    @classmethod
    def from_settings(cls, settings) -> "LinearAlgebra":
        """From a ``[solver]`` table (:class:`tofsi.scene.settings.SolverSettings`): ``auto`` resolved
        to the fastest installed backend, an unavailable one refused (InputError naming why),
        ``threads = 0`` one per core; the environment's overrides applied."""
        from tofsi.linalg.backends import requested, resolve
        name = requested(settings.linear_solver)
        return cls(resolve(name), solver_threads(settings.threads),
                   environment_int("TOFSI_BLAS_THREADS", settings.blas_threads), iterative=name == ITERATIVE,
                   adjoint_tol=settings.adjoint_tol)

    @classmethod
    def default(cls) -> "LinearAlgebra":
        """The process default's direct backend (physics and movers built without a model)."""
        from tofsi.linalg.backends import resolve
        return cls(backend=resolve())

    def direct(self, A, perm=None):
        """A :class:`~tofsi.linalg.DirectSolver` of ``A`` on this backend."""
        from tofsi.linalg.direct import DirectSolver
        return DirectSolver(A, perm=perm, backend=self.backend, threads=self.threads)

    def elasticity(self, A, points, perm=None, tol: float = 1e-10, symmetric: bool = True, amg: bool = False):
        """A solver of an elasticity-like system ``A`` (two dofs per node at ``points`` (n, 2)): on
        the iterative path, or when ``amg`` asks for it, smoothed-aggregation AMG with the
        rigid-body modes as near-null space (CG, or GMRES where ``A`` is not ``symmetric``) to
        ``tol``; else the LU on this backend with the ordering ``perm`` (or ``perm()``: an
        ordering made only where an LU needs it)."""
        if self.iterative or amg:
            from tofsi.linalg.amg import AMGSolver, rigid_body_modes
            return AMGSolver(A, near_null=rigid_body_modes(points), tol=tol, symmetric=symmetric)
        return self.direct(A, perm=perm() if callable(perm) else perm)

    def saddle_point(self, factorize, precondition):
        """``A -> solver`` of a saddle-point sequence (the flow's Jacobians): ``factorize`` (its LU)
        on a direct backend, ``precondition`` (its block preconditioner for FGMRES) on the
        iterative path."""
        return precondition if self.iterative else factorize

    def saddle_point_layout(self, whole, blocks):
        """The pattern a saddle-point Jacobian is assembled on: ``whole()`` (the whole CSR
        matrix, for its LU) on a direct backend, ``blocks()`` (its blocks ``A``, ``B``, which
        the block preconditioner keeps without a copy) on the iterative path."""
        return blocks() if self.iterative else whole()

    @contextmanager
    def blas(self):
        """Within the block NumPy's and SciPy's OpenBLAS use ``blas_threads`` threads (restored
        afterwards; nothing changes for 0)."""
        if self.blas_threads <= 0:
            yield
            return
        from threadpoolctl import threadpool_limits
        with threadpool_limits(limits=self.blas_threads, user_api="blas"):
            yield
