"""Smooth indicators of where the solid is, and element layers measured from the evolving solid.

The soft "any": for values ``v`` in [0, 1] combined over index sets ``T_r``,

    any_r(v) = 1 - prod_{j in T_r} (1 - v_j),

a polynomial (smooth for any values), 1 as soon as one member is 1, 0 when all
are 0. Over the elements at a node it is the *solid indicator* of a node
(``s_i``, the density blend of the mesh motion); over the nodes of an element
it dilates a nodal indicator back to the elements. One step of both,

    D_k = dilate(D_(k-1)),   D_0 = rho,

grows the solid by one element layer, smoothly: ``L_k = D_k - D_(k-1)`` is the
k-th layer around the (possibly gray) solid, and for 0/1 densities exactly the
k-th layer of the breadth-first search over shared nodes
(:func:`tofsi.mesh.layers.element_layers`). Density-dependent layered stiffening
(Abdelhamid & Czekanski's proposal for an evolving interface) uses

    f_e = 1 + sum_(k=1..K) (c_k - 1) L_k,e,

so a gray element is partly stiffened and every factor is differentiable in rho.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def node_element_table(quads: np.ndarray, n_nodes: int) -> np.ndarray:
    """Elements around each node ``(n, m)``, padded with -1."""
    nodes = quads.ravel()
    elems = np.repeat(np.arange(len(quads)), quads.shape[1])
    order = np.argsort(nodes, kind="stable")
    nodes, elems = nodes[order], elems[order]
    counts = np.bincount(nodes, minlength=n_nodes)
    starts = np.cumsum(counts) - counts
    table = np.full((n_nodes, counts.max()), -1, dtype=np.int64)
    table[nodes, np.arange(nodes.size) - starts[nodes]] = elems
    return table


def soft_any(values: np.ndarray, table: np.ndarray):
    """``s_r = 1 - prod_j (1 - values[table[r, j]])`` (rows padded with -1) and ``ds/dvalues``
    as a sparse ``(rows, len(values))`` matrix."""
    values = np.asarray(values, dtype=float)
    valid = table >= 0
    t = np.where(valid, 1.0 - values[np.where(valid, table, 0)], 1.0)          # (r, m)
    s = 1.0 - np.prod(t, axis=1)
    ones = np.ones((table.shape[0], 1))
    before = np.cumprod(np.hstack([ones, t[:, :-1]]), axis=1)                 # prod of t[:, :k]
    after = np.cumprod(np.hstack([ones, t[:, :0:-1]]), axis=1)[:, ::-1]       # prod of t[:, k+1:]
    rows = np.repeat(np.arange(table.shape[0]), table.shape[1])[valid.ravel()]
    ds = sp.csr_matrix(((before * after)[valid], (rows, table[valid])), shape=(table.shape[0], values.size))
    return s, ds


def solid_indicator(rho: np.ndarray, quads: np.ndarray, n_nodes: int):
    """Nodal ``s (n,) = 1 - prod_{e at i}(1 - rho_e)`` and ``ds/drho`` as a sparse ``(n, E)`` matrix."""
    return soft_any(rho, node_element_table(quads, n_nodes))


class DensityLayers:
    """Stiffening factors ``f (E,)`` of element layers grown from the densities (see above).

    factors : ``c_k`` of layers ``k = 1..K`` (``mover.layers``)
    """

    def __init__(self, quads: np.ndarray, n_nodes: int, factors):
        self.quads = np.asarray(quads)
        self.table = node_element_table(self.quads, n_nodes)
        self.c = np.asarray(factors, dtype=float)

    def layers(self, rho: np.ndarray):
        """``[D_0, ..., D_K]`` and the Jacobians ``dD_k/dD_(k-1)`` (sparse, E x E)."""
        D, steps = [np.asarray(rho, dtype=float)], []
        for _ in range(len(self.c)):
            nodal, dn = soft_any(D[-1], self.table)
            grown, de = soft_any(nodal, self.quads)
            D.append(grown)
            steps.append(de @ dn)
        return D, steps

    def factors(self, rho: np.ndarray) -> np.ndarray:
        """``f_e = 1 + sum_k (c_k - 1)(D_k - D_(k-1))`` (E,)."""
        D, _ = self.layers(rho)
        return 1.0 + sum((c - 1.0) * (D[k + 1] - D[k]) for k, c in enumerate(self.c))

    def transpose(self, rho: np.ndarray, f_bar: np.ndarray) -> np.ndarray:
        """``(df/drho)^T f_bar`` (E,): reverse through the dilation steps."""
        _, steps = self.layers(rho)
        a = self.c - 1.0
        weight = np.append(a, 0.0)                  # f = 1 - a_1 D_0 + sum_k (a_k - a_(k+1)) D_k
        bar = (weight[-2] - weight[-1]) * f_bar
        for k in range(len(self.c), 0, -1):         # D_k's adjoint -> D_(k-1)'s
            below = -a[0] * f_bar if k == 1 else (weight[k - 2] - weight[k - 1]) * f_bar
            bar = steps[k - 1].T @ bar + below
        return bar
