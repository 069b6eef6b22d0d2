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
    int32 per element value while ``nnz < 2^31``), the triplet indices and
    ``keep`` are not. Each assembly then adds the element values into their
    slots in element order (``np.add.at``: no index copy, and by chunks of
    elements with :meth:`add`, so the element matrices need not all be held),
    the same sums in the same order every time, so results never depend on how
    many assemblies came before (bitwise reproducible runs).
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

    def _ensure_slots(self, chunk: int = 4096) -> None:
        """The CSR structure and every element value's slot, without the triplets: the pattern
        is the product of the rows' and the columns' element incidences (scipy's sparse
        product, no duplicates formed), and the slots are searched chunk by chunk of elements
        among the sorted keys ``row * n_cols + col`` (at most about 3 int64 per nonzero held
        at once: a sixth of the triplets' COO-to-CSR conversion)."""
        if self.element_slot is not None:
            return
        E, a = self.element_rows.shape
        b = self.element_cols.shape[1]
        n_rows, n_cols = self.shape
        k = self.diagonal.size                                     # the extra diagonal: 1 x 1 "elements"
        rows = sp.csc_matrix((np.ones(E * a + k, dtype=np.float32), np.r_[self.element_rows.ravel(), self.diagonal],
                              np.r_[np.arange(0, E * a + 1, a), E * a + 1 + np.arange(k)]), shape=(n_rows, E + k))
        cols = sp.csr_matrix((np.ones(E * b + k, dtype=np.float32), np.r_[self.element_cols.ravel(), self.diagonal],
                              np.r_[np.arange(0, E * b + 1, b), E * b + 1 + np.arange(k)]), shape=(E + k, n_cols))
        A = rows.tocsr() @ cols
        del rows, cols
        A.sort_indices()
        self.indices, self.indptr = A.indices, A.indptr
        del A
        keys = np.repeat(np.arange(n_rows, dtype=np.int64), np.diff(self.indptr))
        keys *= n_cols
        keys += self.indices                                       # sorted: row-major, columns sorted
        nnz = self.indices.size
        index = np.int32 if nnz < np.iinfo(np.int32).max else np.int64
        self.diagonal_slot = np.searchsorted(keys, self.diagonal * n_cols + self.diagonal).astype(index)
        self.element_slot = np.empty((E, a * b), dtype=index)    # (E, a b); dropped values: nnz
        for start in range(0, E, chunk):
            e = slice(start, min(start + chunk, E))
            wanted = (self.element_rows[e, :, None].astype(np.int64) * n_cols + self.element_cols[e, None, :])
            slot = np.searchsorted(keys, wanted.reshape(wanted.shape[0], -1))
            if self.keep is not None:
                slot = np.where(self.keep[e].reshape(slot.shape), slot, nnz)
            self.element_slot[e] = slot
        self.keep = None

    @property
    def nnz(self) -> int:
        self._ensure_slots()
        return int(self.indices.size)

    def zeros(self, dtype=float) -> np.ndarray:
        """A zero data array to :meth:`add` element values into (``nnz + 1``: the last slot
        takes the dropped values)."""
        return np.zeros(self.nnz + 1, dtype=dtype)

    def add(self, data: np.ndarray, elements: slice, values: np.ndarray) -> None:
        """Add the values ``(e, a, b)`` of the elements ``elements`` (a slice) into ``data``."""
        np.add.at(data, self.element_slot[elements].reshape(-1), values.reshape(-1))

    def matrix(self, data: np.ndarray, diagonal: np.ndarray | float | None = None):
        """The CSR matrix of ``data`` (from :meth:`zeros` and :meth:`add`) with the extra
        diagonal entries added last."""
        data = data[:self.nnz]
        if self.diagonal_slot.size:
            np.add.at(data, self.diagonal_slot, 0.0 if diagonal is None else diagonal)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)

    def assemble(self, values: np.ndarray, diagonal: np.ndarray | float | None = None):
        """CSR matrix from element values ``(E, a, b)`` and the extra diagonal entries
        (element values first, then the diagonal, in that order every time)."""
        data = self.zeros(values.dtype)
        self.add(data, slice(None), values)
        return self.matrix(data, diagonal)


def assemble_vector(dofs: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Global vector from element vectors ``values`` ``(E, a)`` on ``dofs`` ``(E, a)``."""
    return np.bincount(dofs.ravel(), weights=values.ravel(), minlength=size)


class SaddlePattern:
    """A constrained saddle-point Jacobian's pattern, velocities first (``n_velocity``), as its
    blocks: every element value's slot in one data array ``[A | B]`` (``A`` the velocity rows
    and columns, ``B`` the pressure rows' velocity columns, both CSR in the order of ``pattern``).
    The (v, p) block, which is ``B^T`` exactly, and the (p, p) block (zero but for the pinned
    pressures' identity, ``C = diag(pinned)``) get no slot: their values go to a last, discarded
    slot. :meth:`matrix` gives a :class:`~tofsi.linalg.block_matrix.SaddlePointMatrix` whose
    ``A`` and ``B`` share this pattern's index arrays (a preconditioner keeping them copies
    nothing). The slots come from ``pattern`` (a :class:`SparsePattern` of the whole matrix,
    made for this and let go: a second copy of the slots is not kept)."""

    def __init__(self, pattern: SparsePattern, n_velocity: int, pinned: np.ndarray):
        nnz, nv = pattern.nnz, n_velocity
        indptr, indices = pattern.indptr, pattern.indices
        velocity = indices[:nnz] < nv                               # (nnz,) the A and B entries
        rank = np.concatenate([[0], np.cumsum(velocity, dtype=np.int64)])   # A | B order of the velocity entries
        self.nnz_a, self.nnz = int(rank[indptr[nv]]), int(rank[-1])
        counts = rank[indptr[1:]] - rank[indptr[:-1]]
        index = np.int32 if self.nnz < np.iinfo(np.int32).max else np.int64
        destination = np.where(velocity, rank[:-1], self.nnz).astype(index)
        destination = np.append(destination, index(self.nnz))     # SparsePattern's dropped slot
        del rank
        self.a_indptr = np.concatenate([[0], np.cumsum(counts[:nv])]).astype(indptr.dtype)
        self.b_indptr = np.concatenate([[0], np.cumsum(counts[nv:])]).astype(indptr.dtype)
        top = int(indptr[nv])
        self.a_indices = indices[:top][velocity[:top]]
        self.b_indices = indices[top:][velocity[top:]]
        del velocity
        self.element_slot = destination[pattern.element_slot]       # (E, a b)
        self.diagonal_slot = destination[pattern.diagonal_slot]
        self.shape, self.n_velocity = pattern.shape, nv
        self.pinned = np.asarray(pinned, dtype=float)

    def zeros(self, dtype=float) -> np.ndarray:
        """A zero data array ``[A | B | discarded]`` to :meth:`add` element values into."""
        return np.zeros(self.nnz + 1, dtype=dtype)

    def add(self, data: np.ndarray, elements: slice, values: np.ndarray) -> None:
        """Add the values ``(e, a, b)`` of the elements ``elements`` (a slice) into ``data``."""
        np.add.at(data, self.element_slot[elements].reshape(-1), values.reshape(-1))

    def matrix(self, data: np.ndarray, diagonal: float = 1.0):
        """The Jacobian of ``data`` with ``diagonal`` on the fixed velocities' rows (the pinned
        pressures' is ``C``)."""
        from tofsi.linalg.block_matrix import SaddlePointMatrix
        np.add.at(data, self.diagonal_slot, diagonal)
        nv, n = self.n_velocity, self.shape[0]
        A = sp.csr_matrix((data[:self.nnz_a], self.a_indices, self.a_indptr), shape=(nv, nv))
        B = sp.csr_matrix((data[self.nnz_a:self.nnz], self.b_indices, self.b_indptr), shape=(n - nv, nv))
        return SaddlePointMatrix(A, B, self.pinned)
