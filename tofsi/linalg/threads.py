"""Threads of the BLAS and of the sparse direct solver, chosen deliberately.

Measured on the project's 2-core machine (``benchmarks/README.md``): one
OpenBLAS thread costs nothing on a quiet machine and removes 2-7x slowdowns
when the machine is shared (the spring mover went from 2.5 s to 11-18 s with
two threads under load), because NumPy's BLAS calls here are many small
products whose threads spin against each other. The sparse direct solver
(PARDISO) does gain from threads, so it gets one per core. Both are
overridable: ``[solver] blas_threads`` / ``threads`` in a scene, or the
environment variables ``TOFSI_BLAS_THREADS`` / ``TOFSI_THREADS``, which win
(as ``TOFSI_LINEAR_SOLVER`` does for ``[solver] linear_solver``).
"""

from __future__ import annotations

import logging
import os

from tofsi.linalg.choice import LinearAlgebra, environment_int, solver_threads

__all__ = ["configure", "mpi_rank", "set_blas_threads", "solver_threads"]
log = logging.getLogger(__name__)


def set_blas_threads(requested: int = 1) -> int | None:
    """Limit OpenBLAS (NumPy's and SciPy's) to ``requested`` threads; 0 leaves it alone.

    Returns the limit applied (None when nothing was changed). MKL's own thread
    count is the solver's (:func:`solver_threads`), not touched here.
    """
    n = environment_int("TOFSI_BLAS_THREADS", requested)
    if n <= 0:
        return None
    import numpy.linalg  # noqa: F401  - load NumPy's and SciPy's OpenBLAS, so both are limited
    import scipy.linalg  # noqa: F401
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:                       # pragma: no cover - a dependency
        log.warning("threadpoolctl missing: BLAS threads left as they are")
        return None
    ThreadpoolController().select(internal_api="openblas").limit(limits=n)
    return n


def configure(settings) -> LinearAlgebra:
    """Apply a scene's ``[solver]`` table to the process (the command line owns its process):
    the default backend of solvers made without a model, its threads, and the BLAS threads.
    Models do not call this: each keeps its own :class:`~tofsi.linalg.LinearAlgebra`.
    ``TOFSI_LINEAR_SOLVER`` in the environment overrides the scene's backend."""
    from tofsi.linalg import backends
    linear_algebra = LinearAlgebra.from_settings(settings)
    backends.set_default(linear_algebra.backend)
    set_blas_threads(linear_algebra.blas_threads)
    backends.set_threads(linear_algebra.threads)
    return linear_algebra


def mpi_rank() -> int:
    """This process's rank under ``mpiexec`` (0 when not started by an MPI launcher)."""
    for name in ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK", "MV2_COMM_WORLD_RANK"):
        if os.environ.get(name, "").isdigit():
            return int(os.environ[name])
    return 0
