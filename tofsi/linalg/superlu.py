"""SciPy's SuperLU as a backend: the ordering and the permuted pattern are the analysis.

SuperLU (through ``scipy.sparse.linalg.splu``) has no separate symbolic
phase to keep, but everything around it depends on the pattern only: with a
fill-reducing permutation ``p`` SuperLU factorizes ``B = A[p][:, p]`` in CSC
form with its natural column order. The analysis computes, once per pattern,
where every CSR entry of ``A`` lands in ``B``'s CSC data array (``take``), so
a new factorization gathers ``B.data = A.data[take]`` instead of two fancy
index operations and a format conversion. Diagonal pivots are kept unless
below 1e-6 of the column's largest entry (the ordering's low fill; saddle-point
systems need their pressures ordered last within each block).

SuperLU sizes its factors' arrays from an estimate of the fill (``sp_ienv(6)``:
30 times the matrix's non-zeros for ``L`` and for ``U``, expanded if short,
never shrunk), 5-14 times what the factors use on the meshes here, and writes
only part of it. Fresh mappings leave the rest out of memory; but glibc's heap
serves them from memory earlier arrays wrote and freed, which stays resident.
A caller that keeps many factorizations (a move in increments keeps one per
increment for its derivatives) first gives those pages back,
:func:`release_free_pages`.
"""

from __future__ import annotations

import ctypes
import ctypes.util

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tofsi.core.errors import NumericalError

INDEX_BYTES = 4


def unavailable() -> str | None:
    return None                                    # part of SciPy


def _glibc():
    """glibc (None elsewhere: macOS, musl)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None
    glibc = hasattr(libc, "gnu_get_libc_version") and hasattr(libc, "malloc_trim")
    return libc if glibc else None


_LIBC = _glibc()
GLIBC = _LIBC is not None


def release_free_pages() -> None:
    """Give the heap's free pages back to the system (glibc's ``malloc_trim``; a no-op
    elsewhere), so that what is allocated next starts from pages nothing has written."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


class Backend:
    name = "superlu"

    def __init__(self):
        self.analyses = 0
        self.factorizations = 0

    def analyse(self, pattern, perm):
        return Analysis(self, pattern, perm)

    def set_threads(self, n: int) -> None:
        """SuperLU is sequential."""


class Analysis:
    """Permuted CSC pattern of ``A[p][:, p]`` and the gather map from ``A``'s CSR data."""

    def __init__(self, backend: Backend, pattern, perm: np.ndarray | None):
        self.backend, self.pattern, self.perm = backend, pattern, perm
        n = pattern.shape[0]
        marker = sp.csr_matrix((np.arange(1, pattern.nnz + 1, dtype=np.float64),
                                pattern.indices, pattern.indptr), shape=pattern.shape)
        if perm is not None:
            marker = marker[perm][:, perm]
        B = marker.tocsc()
        B.sort_indices()
        self.take = B.data.astype(np.int64) - 1         # exact: nnz < 2**53
        self.indices, self.indptr = B.indices, B.indptr
        self.options = (dict(permc_spec="MMD_AT_PLUS_A") if perm is None
                        else dict(permc_spec="NATURAL", diag_pivot_thresh=1e-6))
        self.n = n

    def factorize(self, A: sp.csr_matrix) -> "Factorization":
        B = sp.csc_matrix((A.data[self.take], self.indices, self.indptr), shape=self.pattern.shape)
        try:
            lu = spla.splu(B, **self.options)
        except RuntimeError as err:        # "Factor is exactly singular"
            raise NumericalError(f"sparse LU failed: {err}",
                                 {"size": self.n, "nnz": self.pattern.nnz}) from None
        self.backend.factorizations += 1
        return Factorization(lu, self.perm, B.dtype)


class Factorization:
    """SuperLU factors of the permuted matrix; ``solve(b, "N" | "T")``."""

    def __init__(self, lu, perm, dtype):
        self.lu, self.perm, self.dtype = lu, perm, np.dtype(dtype)
        self.factor_nnz = int(lu.nnz)                   # L + U
        self.memory_bytes = self.factor_nnz * (self.dtype.itemsize + INDEX_BYTES)

    def solve(self, b: np.ndarray, trans: str = "N") -> np.ndarray:
        if self.perm is None:
            return self.lu.solve(b, trans=trans)
        x = np.empty_like(b, dtype=np.result_type(b, self.dtype))
        x[self.perm] = self.lu.solve(np.ascontiguousarray(b[self.perm]), trans=trans)
        return x
