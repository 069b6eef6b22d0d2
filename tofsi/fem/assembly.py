"""Sparse assembly from element matrices on a pattern computed once.

``SparsePattern`` is built once from the element dof map (top88's iK/jK);
each assembly then only sums element values into the CSR data array with
``np.bincount`` -- no sorting, no index arrays rebuilt per iteration.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def element_dofs(conn: np.ndarray, n_components: int) -> np.ndarray:
    """Node-interleaved dofs ``(E, k * c)``: node ``i`` owns ``c i, ..., c i + c - 1``."""
    c = n_components
    return (c * conn[:, :, None] + np.arange(c)).reshape(conn.shape[0], -1)


class SparsePattern:
    """CSR pattern of ``sum_e P_e^T K_e Q_e`` for row dofs ``rows`` and column dofs ``cols``.

    rows ``(E, a)``, cols ``(E, b)``; :meth:`assemble` takes values ``(E, a, b)``.
    ``extra_diagonal`` adds diagonal slots (e.g. for Dirichlet rows) that
    :meth:`assemble` fills from ``diagonal``. ``keep`` ``(E, a, b)`` (boolean)
    drops the element values where it is False (Dirichlet rows and columns) in
    the scatter itself, without a masked copy of the element matrices; the
    dropped entries stay in the pattern as zeros, so every matrix of a
    pattern has the same structure and one solver analysis serves them all.

    On the first assembly the CSR structure comes from scipy's COO-to-CSR
    conversion and every element value gets its slot in the CSR data array
    (dropped values the slot ``nnz``, cut off); only the slots are kept (one
    int64 per element value), the triplet indices are not. Each assembly is
    then one ``bincount``, summing in the same order every time, so results
    never depend on how many assemblies came before (bitwise reproducible runs).
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int],
                 extra_diagonal: np.ndarray | None = None, keep: np.ndarray | None = None):
        self.element_rows, self.element_cols = np.asarray(rows), np.asarray(cols)
        E, a = self.element_rows.shape
        b = self.element_cols.shape[1]
        self.diagonal = (np.zeros(0, dtype=np.int64) if extra_diagonal is None
                         else np.asarray(extra_diagonal, dtype=np.int64))
        self.shape = shape
        self.n_element_values = E * a * b
        self.keep = None if keep is None else np.broadcast_to(keep, (E, a, b))
        self.element_slot = None             # (E a b,) slot of every element value (dropped: nnz)
        self.diagonal_slot = None
        self.indices = self.indptr = None

    def _triplets(self):
        E, a = self.element_rows.shape
        b = self.element_cols.shape[1]
        rows = np.concatenate([np.broadcast_to(self.element_rows[:, :, None], (E, a, b)).ravel(), self.diagonal])
        cols = np.concatenate([np.broadcast_to(self.element_cols[:, None, :], (E, a, b)).ravel(), self.diagonal])
        return rows.astype(np.int64), cols.astype(np.int64)

    def _ensure_slots(self) -> None:
        if self.element_slot is not None:
            return
        rows, cols = self._triplets()
        A = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=self.shape).tocsr()
        A.sum_duplicates()
        self.indices, self.indptr = A.indices, A.indptr
        del A
        row_of = np.repeat(np.arange(self.shape[0], dtype=np.int64), np.diff(self.indptr))
        keys = row_of * self.shape[1] + self.indices
        del row_of
        slot = np.searchsorted(keys, rows * self.shape[1] + cols)
        del keys, rows, cols
        n = self.n_element_values
        self.diagonal_slot = slot[n:].copy()
        self.element_slot = (slot[:n] if self.keep is None
                             else np.where(self.keep.ravel(), slot[:n], self.indices.size))

    @property
    def nnz(self) -> int:
        self._ensure_slots()
        return int(self.indices.size)

    def assemble(self, values: np.ndarray, diagonal: np.ndarray | float | None = None):
        """CSR matrix from element values ``(E, a, b)`` and the extra diagonal entries
        (element values first, then the diagonal, in that order every time)."""
        self._ensure_slots()
        nnz = self.nnz
        values = values.reshape(-1)
        if np.iscomplexobj(values):
            data = (np.bincount(self.element_slot, weights=values.real, minlength=nnz + 1)
                    + 1j * np.bincount(self.element_slot, weights=values.imag, minlength=nnz + 1))[:nnz]
        else:
            data = np.bincount(self.element_slot, weights=values, minlength=nnz + 1)[:nnz]
        if self.diagonal_slot.size:
            np.add.at(data, self.diagonal_slot, 0.0 if diagonal is None else diagonal)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


def assemble_vector(dofs: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Global vector from element vectors ``values`` ``(E, a)`` on ``dofs`` ``(E, a)``."""
    return np.bincount(dofs.ravel(), weights=values.ravel(), minlength=size)
