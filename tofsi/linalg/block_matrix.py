"""A square matrix kept as its field blocks: products without assembling it.

A coupled Jacobian ``[[dR_a/dz_b]]`` is made of blocks the fields already own
(their Jacobians and their couplings). Krylov solvers need only its products
``A v`` and ``A^T v``, and a block preconditioner only its diagonal blocks
and the blocks below (or above) them, so the blocks are kept as they are:
no stacking into one sparse matrix per Newton step, no slicing it back into
blocks for the preconditioner. :meth:`BlockMatrix.tocsr` assembles the whole
matrix where a whole-matrix factorization asks for it.

A block off the diagonal may be a :class:`LinearMap`: products only (e.g. the
derivative of a map computed by a sweep, never assembled). The matrix then
multiplies and preconditions, but does not assemble (:attr:`BlockMatrix.assembled`).

    A = BlockMatrix({(0, 0): A00, (0, 2): A02, ...}, sizes=(n0, n1, n2))
    A @ v, A.T @ v, A.sub((1, 2), (1, 2)).tocsr()
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tofsi.linalg.backends import canonical_csr


class LinearMap:
    """A matrix known by its products ``v -> A v`` and ``w -> A^T w`` only (float vectors of
    ``shape``). It keeps its last product of each kind, keyed by the vector: a block
    preconditioner's sweep and the Krylov product after it often multiply the same vector."""

    dtype = np.dtype(float)
    nnz = 0

    def __init__(self, shape, matvec, rmatvec):
        self.shape = tuple(int(s) for s in shape)
        self._apply = {False: matvec, True: rmatvec}
        self._last = {False: None, True: None}

    def product(self, v: np.ndarray, transpose: bool = False) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        last = self._last[transpose]
        if last is None or not np.array_equal(last[0], v):
            last = self._last[transpose] = (v.copy(), np.asarray(self._apply[transpose](v), dtype=float))
        return last[1].copy()

    def __matmul__(self, v):
        return self.product(v)

    @property
    def T(self) -> "_TransposedMap":
        return _TransposedMap(self)


class _TransposedMap:
    """``A^T`` of a :class:`LinearMap` (its products, the same memory)."""

    dtype = np.dtype(float)
    nnz = 0

    def __init__(self, of: LinearMap):
        self.of, self.shape = of, of.shape[::-1]

    def __matmul__(self, v):
        return self.of.product(v, transpose=True)

    @property
    def T(self) -> LinearMap:
        return self.of


def _is_map(B) -> bool:
    return isinstance(B, (LinearMap, _TransposedMap))


class BlockMatrix:
    """``blocks[(i, j)]`` (sparse, or absent: zero) of a matrix whose unknowns are stacked in
    blocks of ``sizes``; immutable. ``A @ v``, ``A.T``, :meth:`sub` and :meth:`tocsr`.
    ``origin``: what the blocks were computed from, where the caller knows it (a Newton's
    iterate: :class:`tofsi.coupling.jacobian_point.JacobianPoint`), so that factors made of them
    can name it; None where unknown (not kept by :attr:`T` or :meth:`sub`)."""

    def __init__(self, blocks: dict, sizes, origin=None):
        self.origin = origin
        self.sizes = tuple(int(s) for s in sizes)
        self.starts = np.concatenate([[0], np.cumsum(self.sizes)]).astype(int)
        n = int(self.starts[-1])
        self.shape = (n, n)
        self.blocks = {}
        for (i, j), B in blocks.items():
            if B is None:
                continue
            if B.shape != (self.sizes[i], self.sizes[j]):
                raise ValueError(f"block ({i}, {j}) is {B.shape}, not {(self.sizes[i], self.sizes[j])}")
            self.blocks[(i, j)] = B
        self.dtype = np.result_type(*[B.dtype for B in self.blocks.values()]) if self.blocks else np.float64
        self.nnz = sum(B.nnz for B in self.blocks.values())
        self.assembled = not any(_is_map(B) for B in self.blocks.values())   # tocsr() possible

    @classmethod
    def from_sparse(cls, A, sizes) -> "BlockMatrix":
        """The blocks of an assembled square matrix ``A`` cut at ``sizes``."""
        A = canonical_csr(A)
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        if starts[-1] != A.shape[0] or A.shape[0] != A.shape[1]:
            raise ValueError(f"block sizes {list(sizes)} do not make up the {A.shape} matrix")
        blocks = {}
        for i in range(len(sizes)):
            rows = A[starts[i]:starts[i + 1]]
            for j in range(len(sizes)):
                B = rows[:, starts[j]:starts[j + 1]]
                if B.nnz:
                    blocks[(i, j)] = B.tocsr()
        return cls(blocks, sizes)

    def _apply(self, v: np.ndarray, transpose: bool) -> np.ndarray:
        v = np.asarray(v)
        out = np.zeros(self.shape[0], dtype=np.result_type(self.dtype, v.dtype))
        s = self.starts
        for (i, j), B in self.blocks.items():
            if transpose:
                out[s[j]:s[j + 1]] += B.T @ v[s[i]:s[i + 1]]
            else:
                out[s[i]:s[i + 1]] += B @ v[s[j]:s[j + 1]]
        return out

    def matvec(self, v: np.ndarray) -> np.ndarray:
        return self._apply(np.ravel(v), False)

    def rmatvec(self, v: np.ndarray) -> np.ndarray:
        return self._apply(np.ravel(v), True)

    def __matmul__(self, v):
        if sp.issparse(v) or np.ndim(v) != 1:
            raise TypeError("a BlockMatrix multiplies vectors (tocsr() for anything else)")
        return self.matvec(v)

    @property
    def T(self) -> "BlockMatrix":
        """The transposed matrix (the blocks' transposes, no copies)."""
        return BlockMatrix({(j, i): B.T for (i, j), B in self.blocks.items()}, self.sizes)

    def sub(self, rows, cols) -> "BlockMatrix":
        """The matrix of the block rows ``rows`` and block columns ``cols`` (tuples of indices);
        rectangular ones have ``shape`` (rows' size, cols' size)."""
        rows, cols = tuple(rows), tuple(cols)
        blocks = {(a, b): self.blocks[(i, j)] for a, i in enumerate(rows) for b, j in enumerate(cols)
                  if (i, j) in self.blocks}
        return _Rectangular(blocks, [self.sizes[i] for i in rows], [self.sizes[j] for j in cols])

    def tocsr(self) -> sp.csr_matrix:
        """The assembled matrix (canonical CSR); a matrix with a :class:`LinearMap` block raises."""
        if not self.assembled:
            raise TypeError("a block of this matrix is known by its products only (a LinearMap): "
                            "it cannot be assembled")
        return _Rectangular(self.blocks, self.sizes, self.sizes).tocsr()


class _Rectangular:
    """Block rows by block columns, for products (``@``) and assembly (``tocsr``) only."""

    def __init__(self, blocks: dict, row_sizes, col_sizes):
        self.blocks = blocks
        self.row_sizes, self.col_sizes = list(row_sizes), list(col_sizes)
        self.row_starts = np.concatenate([[0], np.cumsum(self.row_sizes)]).astype(int)
        self.col_starts = np.concatenate([[0], np.cumsum(self.col_sizes)]).astype(int)
        self.shape = (int(self.row_starts[-1]), int(self.col_starts[-1]))

    def __bool__(self) -> bool:
        return bool(self.blocks)

    def __matmul__(self, v: np.ndarray) -> np.ndarray:
        out = np.zeros(self.shape[0], dtype=np.result_type(v.dtype, *[B.dtype for B in self.blocks.values()]))
        r, c = self.row_starts, self.col_starts
        for (i, j), B in self.blocks.items():
            out[r[i]:r[i + 1]] += B @ v[c[j]:c[j + 1]]
        return out

    @property
    def T(self) -> "_Rectangular":
        return _Rectangular({(j, i): B.T for (i, j), B in self.blocks.items()}, self.col_sizes, self.row_sizes)

    def tocsr(self) -> sp.csr_matrix:
        rows = []
        for i, m in enumerate(self.row_sizes):         # CSR fast paths: no COO round trip, unlike bmat
            parts = [canonical_csr(self.blocks[(i, j)]) if (i, j) in self.blocks else sp.csr_matrix((m, n))
                     for j, n in enumerate(self.col_sizes)]
            rows.append(sp.hstack(parts, format="csr") if len(parts) > 1 else parts[0])
        A = sp.vstack(rows, format="csr") if len(rows) > 1 else rows[0]
        return canonical_csr(A)


class SaddlePointMatrix(spla.LinearOperator):
    """A constrained saddle-point Jacobian kept as its blocks, velocities first:

        J = | A   B^T |      A (n_v x n_v) and B (n_p x n_v) CSR; the (v, p) block is B^T
            | B   C   |      exactly, C = diag(pinned): 1 on pinned pressures, else 0

    (the flow's Jacobian on the iterative path: its block preconditioner keeps these very
    ``A`` and ``B``, so the Jacobian it is built from is not copied). ``J @ v``, ``J.T @ v``
    and :meth:`absolute_product`; :meth:`tocsr` assembles it."""

    def __init__(self, A, B, pinned: np.ndarray):
        self.A, self.B = A, B
        self.pinned = np.asarray(pinned, dtype=float)                  # (n_p,)
        self.n_velocity = A.shape[0]
        n = A.shape[0] + B.shape[0]
        super().__init__(dtype=np.result_type(A.dtype, B.dtype), shape=(n, n))

    def _product(self, x: np.ndarray, transpose: bool) -> np.ndarray:
        nv = self.n_velocity
        v, p = x[:nv], x[nv:]
        top = (self.A.T @ v if transpose else self.A @ v) + self.B.T @ p
        return np.concatenate([top, self.B @ v + self.pinned * p])

    def _matvec(self, x):
        return self._product(np.ravel(x), False)

    def _rmatvec(self, x):
        return self._product(np.ravel(x), True)

    def absolute_product(self, v: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``|J| v`` (``|J|^T v``)."""
        nv = self.n_velocity
        top = absolute_product(self.A, v[:nv], transpose) + absolute_product(self.B, v[nv:], transpose=True)
        return np.concatenate([top, absolute_product(self.B, v[:nv]) + np.abs(self.pinned) * v[nv:]])

    def tocsr(self) -> sp.csr_matrix:
        return sp.bmat([[self.A, self.B.T], [self.B, sp.diags(self.pinned)]], format="csr")


def absolute_product(M, v: np.ndarray, transpose: bool = False, rows: int = 1 << 16) -> np.ndarray:
    """``|M| v`` (``|M|^T v``) for a CSR ``M`` or a :class:`SaddlePointMatrix`, by blocks of
    ``rows`` rows (``abs(M)``, a copy of the whole matrix, is not formed)."""
    if isinstance(M, SaddlePointMatrix):
        return M.absolute_product(v, transpose)
    M = sp.csr_matrix(M)
    out = np.zeros(M.shape[1] if transpose else M.shape[0])
    for a in range(0, M.shape[0], rows):
        b = min(a + rows, M.shape[0])
        s, e = M.indptr[a], M.indptr[b]
        block = sp.csr_matrix((np.abs(M.data[s:e]), M.indices[s:e], M.indptr[a:b + 1] - s), shape=(b - a, M.shape[1]))
        if transpose:
            out += block.T @ v[a:b]
        else:
            out[a:b] = block @ v
    return out
