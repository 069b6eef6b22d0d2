"""Intel MKL PARDISO as a backend, called through ``ctypes`` (no compiled extension).

``pip install -e ".[fast]"`` installs the ``mkl`` wheel, whose ``libmkl_rt``
exports the C routine

    pardiso(pt, maxfct, mnum, mtype, phase, n, a, ia, ja, perm, nrhs, iparm, msglvl, b, x, error)

used in its three phases: 11 (analysis: ordering and symbolic factorization,
once per pattern), 22 (numerical factorization of new values), 33 (solve;
``iparm[11] = 2`` solves with the transpose). One analysis holds up to
:data:`SLOTS` factorizations of the same pattern at once (``maxfct``); a
factorization owns its slot until it is garbage collected, so an older
factorization that is still in use (e.g. kept for an adjoint) is never
overwritten by a newer one.

The analysis depends on the pattern only: the ordering is the caller's
nested dissection when given (``iparm[4] = 1``, the pressures last within
each block as for SuperLU) and no value-dependent matching or scaling is
used, so a run's results do not depend on which matrix was analysed first
(``tofsi optimize --resume`` is bitwise exact). Small pivots are perturbed
(``iparm[9]``, 1e-13 relative) and the residual check with iterative
refinement in :class:`~tofsi.linalg.DirectSolver` restores full accuracy.

Reproducibility with several threads needs MKL's conditional numerical
reproducibility: ``MKL_CBWR=AUTO,STRICT`` is set before MKL is loaded unless
the environment already sets ``MKL_CBWR``. Memory: ``iparm[14..16]`` report
the analysis peak and the factorization's permanent and working memory [KB].
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import logging
import os
import sys
import weakref

import numpy as np
import scipy.sparse as sp

from tofsi.core.errors import NumericalError

log = logging.getLogger(__name__)

SLOTS = 4                      # factorizations of one pattern alive at the same time
REAL_UNSYMMETRIC = 11
_library: dict = {}


def _candidates() -> list[str]:
    paths = [os.environ.get("TOFSI_MKL_RT", "")]
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        paths += sorted(glob.glob(os.path.join(prefix, "lib", "libmkl_rt.so*")), reverse=True)
    found = ctypes.util.find_library("mkl_rt")
    return [p for p in paths + ([found] if found else []) if p]


def library():
    """The loaded ``libmkl_rt`` (None when MKL is not installed)."""
    if "lib" not in _library:
        os.environ.setdefault("MKL_CBWR", "AUTO,STRICT")       # before MKL reads it
        lib = None
        for path in _candidates():
            try:
                lib = ctypes.CDLL(path)
                lib.pardiso.restype = None
                break
            except (OSError, AttributeError):
                lib = None
        _library["lib"] = lib
    return _library["lib"]


def unavailable() -> str | None:
    if library() is None:
        return 'MKL not found (install the fast extra: pip install -e ".[fast]")'
    return None


def set_threads(n: int) -> None:
    """Threads MKL (and so PARDISO) may use."""
    lib = library()
    if lib is not None:
        lib.MKL_Set_Num_Threads(ctypes.c_int(int(n)))


class Backend:
    name = "pardiso"

    def __init__(self):
        self.analyses = 0
        self.factorizations = 0

    def analyse(self, pattern, perm):
        return Analysis(self, pattern, perm)

    def set_threads(self, n: int) -> None:
        set_threads(n)


def _int(v: int):
    return ctypes.byref(ctypes.c_int32(v))


class Analysis:
    """A PARDISO handle after phase 11 for one pattern (and ordering)."""

    def __init__(self, backend: Backend, pattern, perm: np.ndarray | None):
        self.backend, self.pattern, self.perm = backend, pattern, perm
        self.lib = library()
        self.n = pattern.shape[0]
        self.pt = np.zeros(64, dtype=np.int64)
        self.ia = np.ascontiguousarray(pattern.indptr, dtype=np.int32)
        self.ja = np.ascontiguousarray(pattern.indices, dtype=np.int32)
        self.iparm = np.zeros(64, dtype=np.int32)
        p = self.iparm
        p[0] = 1                      # not the defaults: the values below
        p[1] = 2                      # METIS ordering (when no perm is given)
        p[7] = 0                      # PARDISO's own refinement only after perturbed pivots
        p[9] = 13                     # perturb pivots below 1e-13 of the norm
        p[10] = 0                     # no scaling and
        p[12] = 0                     # no matching: the analysis depends on the pattern only
        p[17] = -1                    # report non-zeros of the factors
        p[34] = 1                     # zero-based indices
        self.user_perm = np.zeros(self.n, dtype=np.int32)
        if perm is not None:
            p[4] = 1                  # our ordering: user_perm[k] = the unknown eliminated k-th
            self.user_perm[:] = perm
        self.slots: list = [None] * SLOTS
        dummy = np.zeros(pattern.nnz)
        self.call(11, 1, dummy, np.zeros(0), np.zeros(0), nrhs=0)
        weakref.finalize(self, _release, self.lib, self.pt, self.ia, self.ja)

    def call(self, phase: int, mnum: int, a, b, x, nrhs: int = 1, iparm=None):
        error = ctypes.c_int32(0)
        iparm = self.iparm if iparm is None else iparm
        self.lib.pardiso(self.pt.ctypes.data_as(ctypes.c_void_p), _int(SLOTS), _int(mnum),
                         _int(REAL_UNSYMMETRIC), _int(phase), _int(self.n),
                         a.ctypes.data_as(ctypes.c_void_p), self.ia.ctypes.data_as(ctypes.c_void_p),
                         self.ja.ctypes.data_as(ctypes.c_void_p),
                         self.user_perm.ctypes.data_as(ctypes.c_void_p), _int(nrhs),
                         iparm.ctypes.data_as(ctypes.c_void_p), _int(0),
                         b.ctypes.data_as(ctypes.c_void_p), x.ctypes.data_as(ctypes.c_void_p),
                         ctypes.byref(error))
        if error.value != 0:
            raise NumericalError(f"PARDISO phase {phase} failed with error {error.value}",
                                 {"size": self.n, "nnz": self.pattern.nnz})

    def release(self, mnum: int) -> None:
        """Phase 0: free the factors in slot ``mnum`` (the analysis stays)."""
        z = np.zeros(1)
        try:
            self.call(0, mnum, z, z, z, nrhs=0, iparm=self.iparm.copy())
        except NumericalError:                             # pragma: no cover
            log.warning("PARDISO could not release slot %d", mnum)

    def _free_slot(self) -> int:
        for k, owner in enumerate(self.slots):
            if owner is None or owner() is None:
                return k
        return -1

    def factorize(self, A: sp.csr_matrix):
        if A.dtype != np.float64:
            raise NumericalError("the pardiso backend solves real systems only", {"dtype": str(A.dtype)})
        k = self._free_slot()
        if k < 0:                     # every slot in use: a second handle for this pattern
            log.info("PARDISO: %d factorizations of one pattern alive; analysing again", SLOTS)
            self.backend.analyses += 1
            return Analysis(self.backend, self.pattern, self.perm).factorize(A)
        a = np.ascontiguousarray(A.data, dtype=np.float64)
        iparm = self.iparm.copy()
        self.call(22, k + 1, a, np.zeros(0), np.zeros(0), nrhs=0, iparm=iparm)
        self.backend.factorizations += 1
        factor = Factorization(self, k + 1, iparm)
        self.slots[k] = weakref.ref(factor)
        weakref.finalize(factor, self.release, k + 1)
        return factor


class Factorization:
    """PARDISO factors in slot ``mnum`` of an analysis; ``solve(b, "N" | "T")``."""

    def __init__(self, analysis: Analysis, mnum: int, iparm: np.ndarray):
        self.analysis, self.mnum = analysis, mnum
        self.iparm = iparm
        self.factor_nnz = int(iparm[17])
        self.memory_bytes = 1024 * (int(iparm[15]) + int(iparm[16]))

    def solve(self, b: np.ndarray, trans: str = "N") -> np.ndarray:
        b = np.asarray(b)
        if np.iscomplexobj(b):
            return self.solve(b.real, trans) + 1j * self.solve(b.imag, trans)
        rhs = np.array(b, dtype=np.float64, order="F")
        x = np.zeros_like(rhs)
        iparm = self.iparm.copy()
        iparm[11] = 0 if trans == "N" else 2
        a = np.zeros(1)               # values are not read in phase 33
        nrhs = 1 if rhs.ndim == 1 else rhs.shape[1]
        self.analysis.call(33, self.mnum, a, rhs, x, nrhs=nrhs, iparm=iparm)
        return x


def _release(lib, pt, ia, ja) -> None:
    """Phase -1: free everything of a handle."""
    error = ctypes.c_int32(0)
    z = np.zeros(1)
    zi = np.zeros(1, dtype=np.int32)
    iparm = np.zeros(64, dtype=np.int32)
    lib.pardiso(pt.ctypes.data_as(ctypes.c_void_p), _int(SLOTS), _int(1), _int(REAL_UNSYMMETRIC),
                _int(-1), _int(1), z.ctypes.data_as(ctypes.c_void_p), ia.ctypes.data_as(ctypes.c_void_p),
                ja.ctypes.data_as(ctypes.c_void_p), zi.ctypes.data_as(ctypes.c_void_p), _int(0),
                iparm.ctypes.data_as(ctypes.c_void_p), _int(0), z.ctypes.data_as(ctypes.c_void_p),
                z.ctypes.data_as(ctypes.c_void_p), ctypes.byref(error))
