"""Slabs of a structured mesh by rank, and the dof numbering that makes each rank's dofs contiguous.

Rank ``r`` of ``P`` owns the elements of columns ``[c_r, c_{r+1})`` (equal
column counts, the channel's long axis cut across) and the dofs of every
node whose fine-grid column ``I`` has element column ``min(I // 2, nx - 1)``
in its slab: a node on a cut belongs to the slab on its right. PETSc wants
each rank's rows contiguous, so the flow's dofs are renumbered rank by rank
(within a rank: its velocity dofs, then its pressure dofs, each in the
flow's order). Only O(n) integer maps are held, identically on every rank;
no global matrix or vector.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def column_cuts(nx: int, ranks: int) -> np.ndarray:
    """``(ranks + 1,)`` element-column boundaries of equal slabs."""
    if ranks > nx:
        raise ValueError(f"{ranks} ranks need at least {ranks} element columns (the mesh has {nx})")
    return np.linspace(0, nx, ranks + 1).round().astype(np.int64)


@dataclass(frozen=True)
class SlabPartition:
    """The flow's elements and dofs split into ``ranks`` slabs; the maps of ``rank``.

    elements : (E_r,) this rank's elements
    new_of_old : (n,) the contiguous numbering of every dof
    ranges : (ranks + 1,) ownership ranges in the new numbering
    velocity, pressure : this rank's owned dofs, new numbering (the fieldsplit's index sets)
    halo_elements : (E_h,) every element touching a dof this rank owns: its slab and the column
        to its left (a node on the left cut is owned here, its left element by the neighbour)
    """

    rank: int
    ranks: int
    elements: np.ndarray
    new_of_old: np.ndarray
    ranges: np.ndarray
    velocity: np.ndarray
    pressure: np.ndarray
    halo_elements: np.ndarray

    @classmethod
    def of(cls, flow, rank: int, ranks: int) -> "SlabPartition":
        mesh = flow.mesh
        cuts = column_cuts(mesh.nx, ranks)
        owner_of_column = np.searchsorted(cuts, np.arange(mesh.nx), side="right") - 1      # (nx,)
        element_column = np.arange(mesh.n_elements) % mesh.nx
        column = flow.grid()[:, 0]                                                       # (n,) fine column
        owner = owner_of_column[np.minimum(column // 2, mesh.nx - 1)]                    # (n,)
        is_pressure = flow.pressure_dofs
        new_of_old, ranges = rank_numbering(owner, ranks, is_pressure)     # velocity before pressure
        mine = owner == rank
        halo = (element_column >= max(cuts[rank] - 1, 0)) & (element_column < cuts[rank + 1])
        return cls(rank, ranks, np.flatnonzero(owner_of_column[element_column] == rank), new_of_old, ranges,
                   np.sort(new_of_old[mine & ~is_pressure]), np.sort(new_of_old[mine & is_pressure]),
                   np.flatnonzero(halo))

    @property
    def owned(self) -> tuple[int, int]:
        return int(self.ranges[self.rank]), int(self.ranges[self.rank + 1])


def rank_numbering(owner: np.ndarray, ranks: int, key: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(new_of_old (n,), ranges (ranks + 1,))``: dofs renumbered rank by rank (within a rank by
    ``key``, then in their own order), so each rank's owned dofs are contiguous."""
    order = np.lexsort((np.arange(owner.size), owner * 2 + (0 if key is None else key)))
    new_of_old = np.empty(owner.size, dtype=np.int64)
    new_of_old[order] = np.arange(owner.size)
    counts = np.bincount(owner, minlength=ranks)
    return new_of_old, np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def row_counts(dofs: np.ndarray, lo: int, hi: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Non-zeros of each owned row ``[lo, hi)`` in the diagonal and off-diagonal blocks
    ``((m,), (m,))`` of a matrix assembled from elements with dofs ``(E_h, k)`` (new numbering;
    every element touching an owned dof): PETSc's exact preallocation."""
    k = dofs.shape[1]
    owned = (dofs >= lo) & (dofs < hi)
    rows = np.repeat(dofs[owned], k)
    cols = np.repeat(dofs, owned.sum(axis=1), axis=0).reshape(-1)                # each owned row: k cols
    pairs = np.unique((rows - lo) * size + cols)
    del rows, cols
    row, col = pairs // size, pairs % size
    inside = (col >= lo) & (col < hi)
    m = hi - lo
    return (np.bincount(row[inside], minlength=m).astype(np.int32),
            np.bincount(row[~inside], minlength=m).astype(np.int32))
