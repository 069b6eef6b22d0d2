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

    The CSR structure comes from scipy's COO-to-CSR conversion once; then
    every triplet gets its slot in the CSR data array and each assembly is one
    ``bincount``. Every assembly sums in the same order, so results never
    depend on how many assemblies came before (bitwise reproducible runs).
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int],
                 extra_diagonal: np.ndarray | None = None, keep: np.ndarray | None = None):
        E, a = rows.shape
        b = cols.shape[1]
        diag = np.zeros(0, dtype=np.int64) if extra_diagonal is None else np.asarray(extra_diagonal)
        self.rows = np.concatenate([np.broadcast_to(rows[:, :, None], (E, a, b)).ravel(), diag])
        self.cols = np.concatenate([np.broadcast_to(cols[:, None, :], (E, a, b)).ravel(), diag])
        self.shape = shape
        self.n_element_values = E * a * b
        self.keep = None if keep is None else np.broadcast_to(keep, (E, a, b)).ravel()
        self.slot = None
        self._csr = None                     # (indices, indptr) once known
        self._element_slot = None            # slots of the element values (dropped ones: nnz)

    def _build_element_slots(self) -> None:
        slot = self.slot[:self.n_element_values]
        self._element_slot = slot if self.keep is None else np.where(self.keep, slot, self._csr[0].size)
        self._diagonal_slot = self.slot[self.n_element_values:]

    def _values(self, values, diagonal):
        values = values.reshape(-1)
        n_diag = self.rows.size - self.n_element_values
        if n_diag:
            d = np.broadcast_to(np.asarray(0.0 if diagonal is None else diagonal), (n_diag,))
            values = np.concatenate([values, d])
        return values

    def _build_slots(self) -> None:
        indices, indptr = self._csr
        row_of = np.repeat(np.arange(self.shape[0], dtype=np.int64), np.diff(indptr))
        keys = row_of * self.shape[1] + indices
        self.slot = np.searchsorted(keys, self.rows.astype(np.int64) * self.shape[1] + self.cols)

    def assemble(self, values: np.ndarray, diagonal: np.ndarray | float | None = None):
        """CSR matrix from element values ``(E, a, b)`` (and the extra diagonal entries)."""
        if self.keep is not None:
            return self._assemble_kept(values, diagonal)
        values = self._values(values, diagonal)
        self._ensure_slots()
        nnz = self._csr[0].size
        if np.iscomplexobj(values):
            data = (np.bincount(self.slot, weights=values.real, minlength=nnz)
                    + 1j * np.bincount(self.slot, weights=values.imag, minlength=nnz))
        else:
            data = np.bincount(self.slot, weights=values, minlength=nnz)
        return sp.csr_matrix((data, self._csr[0], self._csr[1]), shape=self.shape)

    def _assemble_kept(self, values, diagonal):
        """Element values where ``keep``, then the extra diagonal entries, in that order."""
        self._ensure_slots()
        if self._element_slot is None:
            self._build_element_slots()
        nnz = self._csr[0].size
        values = values.reshape(-1)
        if np.iscomplexobj(values):
            data = (np.bincount(self._element_slot, weights=values.real, minlength=nnz + 1)
                    + 1j * np.bincount(self._element_slot, weights=values.imag, minlength=nnz + 1))[:nnz]
        else:
            data = np.bincount(self._element_slot, weights=values, minlength=nnz + 1)[:nnz]
        if self._diagonal_slot.size:
            np.add.at(data, self._diagonal_slot, 0.0 if diagonal is None else diagonal)
        return sp.csr_matrix((data, self._csr[0], self._csr[1]), shape=self.shape)

    def _ensure_slots(self) -> None:
        if self._csr is None:
            A = sp.coo_matrix((np.ones(self.rows.size), (self.rows, self.cols)), shape=self.shape).tocsr()
            A.sum_duplicates()
            self._csr = (A.indices, A.indptr)
        if self.slot is None:
            self._build_slots()


def assemble_vector(dofs: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Global vector from element vectors ``values`` ``(E, a)`` on ``dofs`` ``(E, a)``."""
    return np.bincount(dofs.ravel(), weights=values.ravel(), minlength=size)


def weighted_gram(A: np.ndarray, B: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``sum_g w[e, g] A[e, g]^T B[e, g]`` ``(E, a, b)`` for ``A`` ``(E, G, m, a)``, ``B`` ``(E, G, m, b)``.

    One batched matrix product over the stacked quadrature points.
    """
    E, G, m, a = A.shape
    Aw = (A * w[:, :, None, None]).reshape(E, G * m, a)
    return np.matmul(Aw.transpose(0, 2, 1), B.reshape(E, G * m, B.shape[-1]))
