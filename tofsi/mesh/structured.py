"""Structured quadrilateral meshes of a rectangular channel.

Nodes sit on the tensor grid ``xs`` x ``ys``; node ``(i, j)`` has index
``j (nx + 1) + i`` and element ``(i, j)`` has index ``j nx + i`` with corners
counter-clockwise from the bottom-left::

    3 ---- 2        quads[e] = [n(i, j), n(i+1, j), n(i+1, j+1), n(i, j+1)]
    |      |
    0 ---- 1

The 9-node (Q2) velocity mesh uses the same quads. Its nodes are numbered
corners first (so Q1 node ``k`` is Q2 node ``k``), then horizontal-edge
midpoints, vertical-edge midpoints and element centres; ``quads9[e]`` lists
the corners, the mid-sides bottom/right/top/left, then the centre.

Element regions are tagged ``FLUID``, ``SOLID`` (fixed structure) and
``DESIGN`` (densities decided by the optimizer).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

FLUID, SOLID, DESIGN = 0, 1, 2
REGION_NAMES = {FLUID: "fluid", SOLID: "solid", DESIGN: "design"}
SIDES = ("left", "right", "bottom", "top")


class StructuredQuadMesh:
    """A tensor-grid quad mesh with region tags and node sets.

    Parameters
    ----------
    xs, ys : grid-line coordinates, strictly increasing [m]
    region : (E,) element tags (FLUID, SOLID, DESIGN); default all FLUID
    """

    def __init__(self, xs, ys, region=None):
        self.xs = np.asarray(xs, dtype=float)
        self.ys = np.asarray(ys, dtype=float)
        if self.xs.ndim != 1 or self.ys.ndim != 1 or len(self.xs) < 2 or len(self.ys) < 2:
            raise ValueError("xs and ys need at least two grid lines each")
        if np.any(np.diff(self.xs) <= 0) or np.any(np.diff(self.ys) <= 0):
            raise ValueError("grid lines must be strictly increasing")
        self.nx, self.ny = len(self.xs) - 1, len(self.ys) - 1
        if region is None:
            region = np.full(self.nx * self.ny, FLUID, dtype=np.int8)
        self.region = np.asarray(region, dtype=np.int8)
        if self.region.shape != (self.n_elements,):
            raise ValueError("region needs one tag per element")
        for a in (self.xs, self.ys, self.region):
            a.setflags(write=False)

    # ---- sizes and indexing -------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return (self.nx + 1) * (self.ny + 1)

    @property
    def n_elements(self) -> int:
        return self.nx * self.ny

    @property
    def n_nodes9(self) -> int:
        return (2 * self.nx + 1) * (2 * self.ny + 1)

    def node(self, i, j):
        """Index of grid node ``(i, j)``."""
        return np.asarray(j) * (self.nx + 1) + np.asarray(i)

    # ---- Q1 mesh -------------------------------------------------------------
    @cached_property
    def points(self) -> np.ndarray:
        """Reference node coordinates ``(n, 2)`` [m]."""
        X, Y = np.meshgrid(self.xs, self.ys, indexing="xy")
        return _frozen(np.column_stack([X.ravel(), Y.ravel()]))

    @cached_property
    def quads(self) -> np.ndarray:
        """Corner nodes ``(E, 4)``, counter-clockwise from the bottom-left."""
        i, j = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="xy")
        i, j = i.ravel(), j.ravel()
        return _frozen(np.column_stack([self.node(i, j), self.node(i + 1, j),
                                        self.node(i + 1, j + 1), self.node(i, j + 1)]))

    @cached_property
    def centroids(self) -> np.ndarray:
        """Element centres ``(E, 2)`` on the reference grid [m]."""
        return _frozen(self.points[self.quads].mean(axis=1))

    @cached_property
    def element_sizes(self) -> np.ndarray:
        """Element widths and heights ``(E, 2)`` [m]."""
        return _frozen(np.column_stack([np.tile(np.diff(self.xs), self.ny),
                                        np.repeat(np.diff(self.ys), self.nx)]))

    @cached_property
    def incidence(self) -> sp.csr_matrix:
        """Element-node incidence ``(E, n)``: 1 where the element uses the node."""
        E = self.n_elements
        data = np.ones(4 * E)
        return sp.csr_matrix((data, (np.repeat(np.arange(E), 4), self.quads.ravel())),
                             shape=(E, self.n_nodes))

    def side_nodes(self, side: str) -> np.ndarray:
        """Q1 nodes on a channel side: ``left`` (inlet), ``right`` (outlet), ``bottom``, ``top``."""
        i, j = self._side_grid(side, self.nx, self.ny)
        return self.node(i, j)

    @cached_property
    def boundary_nodes(self) -> np.ndarray:
        """Q1 nodes on the channel's outer boundary (all four sides)."""
        return _frozen(np.unique(np.concatenate([self.side_nodes(s) for s in SIDES])))

    def grid_positions(self) -> np.ndarray:
        """Integer fine-grid positions ``(n, 2)`` of the Q1 nodes: node ``(i, j)`` at ``(2i, 2j)``
        (Q2 nodes fill the odd positions; nested-dissection orderings cut along even lines)."""
        i = np.tile(np.arange(self.nx + 1), self.ny + 1)
        j = np.repeat(np.arange(self.ny + 1), self.nx + 1)
        return np.column_stack([2 * i, 2 * j])

    def nodes_of(self, region: int) -> np.ndarray:
        """Nodes used by at least one element of ``region``."""
        return np.unique(self.quads[self.region == region])

    @cached_property
    def interface_nodes(self) -> np.ndarray:
        """Nodes shared by a SOLID element and a non-solid element."""
        solid = self.region == SOLID
        touches_solid = self.incidence.T @ solid.astype(float) > 0
        touches_other = self.incidence.T @ (~solid).astype(float) > 0
        return _frozen(np.flatnonzero(touches_solid & touches_other))

    @cached_property
    def interface_edges(self) -> np.ndarray:
        """Node pairs ``(m, 2)`` of the element edges between SOLID and non-solid elements."""
        solid = (self.region == SOLID).reshape(self.ny, self.nx)
        j, i = np.nonzero(solid[:, 1:] != solid[:, :-1])           # vertical edges at x_{i+1}
        vertical = np.column_stack([self.node(i + 1, j), self.node(i + 1, j + 1)])
        j, i = np.nonzero(solid[1:, :] != solid[:-1, :])           # horizontal edges at y_{j+1}
        horizontal = np.column_stack([self.node(i, j + 1), self.node(i + 1, j + 1)])
        return _frozen(np.vstack([vertical, horizontal]))

    @cached_property
    def node_sets(self) -> dict[str, np.ndarray]:
        """Named Q1 node sets: inlet, outlet, bottom, top, walls, interface, solid."""
        sets = {"inlet": self.side_nodes("left"), "outlet": self.side_nodes("right"),
                "bottom": self.side_nodes("bottom"), "top": self.side_nodes("top")}
        sets["walls"] = np.union1d(sets["bottom"], sets["top"])
        sets["interface"] = self.interface_nodes
        sets["solid"] = self.nodes_of(SOLID)
        return sets

    # ---- Q2 mesh -------------------------------------------------------------
    def node9(self, I, J):
        """Q2 node index of fine-grid position ``(I, J)``, ``0 <= I <= 2 nx``."""
        I, J = np.asarray(I), np.asarray(J)
        nx, ny, n = self.nx, self.ny, self.n_nodes
        i, j = I // 2, J // 2
        corner = j * (nx + 1) + i
        hmid = n + j * nx + i
        vmid = n + nx * (ny + 1) + j * (nx + 1) + i
        centre = n + nx * (ny + 1) + (nx + 1) * ny + j * nx + i
        odd_i, odd_j = I % 2 == 1, J % 2 == 1
        return np.where(odd_i, np.where(odd_j, centre, hmid), np.where(odd_j, vmid, corner))

    @cached_property
    def quads9(self) -> np.ndarray:
        """Q2 nodes ``(E, 9)``: corners, mid-sides (bottom, right, top, left), centre."""
        i, j = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="xy")
        I, J = 2 * i.ravel(), 2 * j.ravel()
        offsets = [(0, 0), (2, 0), (2, 2), (0, 2), (1, 0), (2, 1), (1, 2), (0, 1), (1, 1)]
        return _frozen(np.column_stack([self.node9(I + a, J + b) for a, b in offsets]))

    @cached_property
    def edges9(self) -> np.ndarray:
        """For every Q2 node the two corner nodes whose mean it is ``(n9, 4)``.

        Corners list themselves four times, mid-sides their edge ends twice,
        centres their four corners: the Q2 node position is the mean of the
        row, which is the bilinear map of the corners, on any deformed mesh.
        """
        rows = np.empty((self.n_nodes9, 4), dtype=np.int64)
        q, q9 = self.quads, self.quads9
        rows[q9[:, :4].ravel()] = np.repeat(q.ravel(), 4).reshape(-1, 4)
        for k, (a, b) in enumerate([(0, 1), (1, 2), (3, 2), (0, 3)]):
            rows[q9[:, 4 + k]] = np.column_stack([q[:, a], q[:, b], q[:, a], q[:, b]])
        rows[q9[:, 8]] = q
        return _frozen(rows)

    def points9(self, points: np.ndarray | None = None) -> np.ndarray:
        """Q2 node coordinates ``(n9, 2)`` of the mesh with corner positions ``points``."""
        P = self.points if points is None else points
        return P[self.edges9].mean(axis=1)

    def side_nodes9(self, side: str) -> np.ndarray:
        """Q2 nodes on a channel side, ordered along it."""
        I, J = self._side_grid(side, 2 * self.nx, 2 * self.ny)
        return self.node9(I, J)

    @staticmethod
    def _side_grid(side: str, nx: int, ny: int):
        if side == "left":
            return np.zeros(ny + 1, int), np.arange(ny + 1)
        if side == "right":
            return np.full(ny + 1, nx), np.arange(ny + 1)
        if side == "bottom":
            return np.arange(nx + 1), np.zeros(nx + 1, int)
        if side == "top":
            return np.arange(nx + 1), np.full(nx + 1, ny)
        raise ValueError(f"side must be one of {SIDES}, got {side!r}")

    def with_regions(self, region: np.ndarray) -> "StructuredQuadMesh":
        """The same grid with other element tags."""
        return StructuredQuadMesh(self.xs, self.ys, region)

    def __repr__(self) -> str:
        counts = {REGION_NAMES[r]: int(np.sum(self.region == r)) for r in REGION_NAMES}
        return (f"StructuredQuadMesh({self.nx} x {self.ny} elements, {self.n_nodes} nodes, "
                f"regions {counts})")


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a
