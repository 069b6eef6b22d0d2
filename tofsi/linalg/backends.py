"""Sparse direct solver backends, chosen by name, with the analysis done once per pattern.

A backend turns a sparsity pattern into an :class:`Analysis` (ordering,
symbolic factorization, index maps: everything that depends on where the
non-zeros are, not on their values) and an analysis turns the values of a
matrix with that pattern into a factorization with ``solve(b, trans)`` and
``memory_bytes``. Newton steps and design iterations change values only, so
one analysis serves them all; the adjoint's transposed solves reuse the
forward factorization.

Backends (``[solver] linear_solver`` in a scene):

* ``superlu`` -- SciPy's SuperLU with the grid's nested-dissection ordering;
  always present, the default, bitwise reproducible;
* ``pardiso`` -- Intel MKL PARDISO through ``ctypes`` (``pip install -e ".[fast]"``
  brings the ``mkl`` wheel); reproducible with ``MKL_CBWR=AUTO,STRICT``, which
  this module sets unless the environment already says otherwise;
* ``petsc`` -- PETSc's LU through MUMPS (petsc4py), distributed under ``mpiexec``;
* ``auto`` -- the fastest available, in the measured order of :data:`AUTO_ORDER`.

Analyses live in a small least-recently-used cache keyed by the backend, the
ordering and the pattern's own ``indptr``/``indices`` arrays (compared by
content, so a cached analysis can never belong to another pattern).
"""

from __future__ import annotations

import importlib
import logging
import os
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tofsi.core.errors import InputError

log = logging.getLogger(__name__)

MODULES = {"superlu": "tofsi.linalg.superlu", "pardiso": "tofsi.linalg.pardiso",
           "petsc": "tofsi.linalg.petsc"}
AUTO_ORDER = ("pardiso", "petsc", "superlu")     # fastest first (benchmarks/README.md)
CHOICES = ("auto", *MODULES)
CACHE_SIZE = 8

_default = {"name": "superlu"}
_instances: dict = {}
_analyses: OrderedDict = OrderedDict()


@dataclass(frozen=True)
class Pattern:
    """The sparsity pattern of a canonical CSR matrix (sorted, no duplicates)."""

    shape: tuple[int, int]
    indptr: np.ndarray
    indices: np.ndarray

    @classmethod
    def of(cls, A: sp.csr_matrix) -> "Pattern":
        return cls(A.shape, A.indptr.copy(), A.indices.copy())     # nobody can change ours

    @property
    def nnz(self) -> int:
        return int(self.indices.size)

    def same(self, A: sp.csr_matrix) -> bool:
        """True when ``A`` has exactly this pattern (content, not identity)."""
        return (A.shape == self.shape and A.indices.size == self.indices.size
                and np.array_equal(A.indptr, self.indptr) and np.array_equal(A.indices, self.indices))


def canonical_csr(A) -> sp.csr_matrix:
    """``A`` as CSR with sorted indices and no duplicates (a copy only when needed)."""
    A = A if sp.isspmatrix_csr(A) else sp.csr_matrix(A)
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    return A


def unavailable(name: str) -> str | None:
    """Why backend ``name`` cannot be used here (None: it can)."""
    if name not in MODULES:
        return f"unknown backend; allowed: {', '.join(CHOICES)}"
    try:
        module = importlib.import_module(MODULES[name])
    except ImportError as err:                  # pragma: no cover - our own modules import
        return str(err)
    return module.unavailable()


def available() -> list[str]:
    """The backends usable in this process, fastest first."""
    return [name for name in AUTO_ORDER if unavailable(name) is None]


def resolve(name: str | None = None) -> str:
    """The backend a name stands for (``None``: ``TOFSI_LINEAR_SOLVER`` if set, else the
    configured default; ``auto``: the fastest)."""
    if name is None:
        name = os.environ.get("TOFSI_LINEAR_SOLVER", "").strip() or _default["name"]
    if name == "auto":
        return available()[0]
    if name == "iterative":                     # the iterative path: what stays direct uses SuperLU
        return "superlu"
    why = unavailable(name)
    if why is not None:
        raise InputError("solver.linear_solver", name, why)
    return name


def get_backend(name: str | None = None):
    """The backend object (one per name and process)."""
    name = resolve(name)
    if name not in _instances:
        _instances[name] = importlib.import_module(MODULES[name]).Backend()
        if "threads" in _default:
            _instances[name].set_threads(_default["threads"])
    return _instances[name]


def set_default(name: str) -> str:
    """Make ``name`` the backend of solvers created without one; returns the previous default."""
    if name not in CHOICES:
        raise InputError("solver.linear_solver", name, f"allowed: {', '.join(CHOICES)}")
    if name != "auto":
        resolve(name)                           # fails now, naming why, if not installed
    previous, _default["name"] = _default["name"], name
    return previous


def default() -> str:
    return _default["name"]


def set_threads(n: int) -> None:
    """Threads of every backend that is loaded and has its own thread pool (PARDISO's MKL)."""
    _default["threads"] = int(n)
    for backend in _instances.values():
        backend.set_threads(n)


def analysis_for(A: sp.csr_matrix, backend, perm: np.ndarray | None):
    """The cached analysis of ``A``'s pattern for ``backend`` and ordering ``perm`` (made once)."""
    for key in reversed(_analyses):
        analysis = _analyses[key]
        if (analysis.backend is backend and analysis.pattern.same(A)
                and _same_perm(analysis.perm, perm)):
            _analyses.move_to_end(key)
            return analysis
    analysis = backend.analyse(Pattern.of(A), None if perm is None else np.array(perm))
    backend.analyses += 1
    _analyses[id(analysis)] = analysis
    while len(_analyses) > CACHE_SIZE:
        _analyses.popitem(last=False)
    return analysis


def clear_cache() -> None:
    """Forget every cached analysis (live factorizations keep theirs)."""
    _analyses.clear()


def _same_perm(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and np.array_equal(a, b)
