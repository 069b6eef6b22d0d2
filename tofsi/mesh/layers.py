"""Element layers counted from the fluid-structure interface, and stiffening fields.

Layer 1 holds the elements that share a node with the interface; layer
``k + 1`` the not yet layered elements that share a node with layer ``k``
(breadth-first search over shared nodes, one sparse product per layer).
Layered selective stiffening multiplies the stiffness of layer ``k`` by
``factors[k - 1]``; every other element keeps factor 1.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def element_layers(incidence: sp.csr_matrix, seed_nodes: np.ndarray, eligible: np.ndarray,
                   n_layers: int | None = None) -> np.ndarray:
    """Layer number ``(E,)`` of each eligible element (0: not in any counted layer).

    incidence : (E, n) element-node incidence
    seed_nodes : the interface nodes
    eligible : (E,) bool, the elements that may be layered (the moving mesh)
    n_layers : stop after this many layers (default: until all are layered)
    """
    E, n = incidence.shape
    layer = np.zeros(E, dtype=np.int32)
    front = np.zeros(n, dtype=bool)
    front[np.asarray(seed_nodes, dtype=np.int64)] = True
    k = 0
    while n_layers is None or k < n_layers:
        touching = (incidence @ front.astype(float) > 0) & eligible & (layer == 0)
        if not touching.any():
            break
        k += 1
        layer[touching] = k
        front = incidence.T @ touching.astype(float) > 0
    return layer


def stiffening_field(layer: np.ndarray, factors) -> np.ndarray:
    """Per-element factors ``(E,)``: ``factors[k - 1]`` on layer ``k``, 1 elsewhere."""
    table = np.r_[1.0, np.asarray(factors, dtype=float), 1.0]
    return table[np.minimum(layer, len(table) - 1)]
