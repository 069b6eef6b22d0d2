"""Band-localized mesh motion: the mover solves only near the moving structure.

Abdelhamid & Czekanski close by proposing to localize the mesh deformation
to the area around the moving structure; SU2's ``DEFORM_LIMIT`` and
Tezduyar's solid-extension technique do the like. The *band* is the set of
moving quads near the structure, either

* within ``layers`` element layers of it (breadth-first search over shared
  nodes, :func:`tofsi.mesh.layers.element_layers`), or
* within a ``distance`` ``D`` [m] of it: a quad is in the band when one of
  its corners is within ``D`` of a structure node (reference mesh), or
* ``auto``: ``D = motion_multiple * max_i |u_i|`` from the structure's
  largest displacement when it is known beforehand (mesh-motion scenes),
  and never fewer than ``layers`` layers; ``layers`` alone when it is not
  (coupled scenes, whose motion is the solution).

Only the band's quads move. The nodes its quads share with quads outside it
form the band's outer edge, held fixed (``x = 0``, a homogeneous Dirichlet
condition, in the forward solve and -- through the same Dirichlet operator --
in the adjoint); every node outside stays. The structure the band is
measured from is the fixed solid (explicit-interface form) or every element
that may become solid, the fixed solid and the design region (density-blended
form), so the band does not depend on the design and the map stays smooth.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tofsi.mesh.layers import element_layers

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Band:
    """Which quads move and which nodes bound them.

    elements : (E,) bool, the quads of the band
    edge_nodes : nodes shared by a band quad and a movable quad outside the band
    outside_nodes : nodes used by a movable quad outside the band (its edge included): held at 0
    reach : the distance [m] the band was built from (None: by layers)
    layers : the element layers the band was built from (None: by distance)
    """

    elements: np.ndarray
    edge_nodes: np.ndarray
    outside_nodes: np.ndarray
    reach: float | None
    layers: int | None

    def as_dict(self) -> dict:
        return {"band_elements": int(self.elements.sum()), "band_edge_nodes": int(self.edge_nodes.size),
                "band_distance": self.reach, "band_layers": self.layers}


def node_distances(points: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """Distance ``(n,)`` of every node to the nearest seed node [m] (one k-d tree query)."""
    return cKDTree(points[seeds]).query(points)[0]


def find_band(mesh, movable: np.ndarray, structure: np.ndarray, settings,
              motion_size: float | None = None) -> Band | None:
    """The band of ``settings`` (:class:`tofsi.scene.settings.BandSettings`), or None when off.

    movable : (E,) bool, the quads the mover may move (the full-domain form)
    structure : (E,) bool, the elements the band is measured from
    motion_size : the structure's largest displacement [m] if known (mode auto)
    """
    mode = settings.mode
    if mode == "off":
        return None
    seeds = np.unique(mesh.quads[structure])
    eligible = movable & ~structure
    reach, layers = None, None
    inside = np.zeros(mesh.n_elements, dtype=bool)
    if mode == "layers" or mode == "auto":
        layers = settings.layers
        inside |= element_layers(mesh.incidence, seeds, eligible, n_layers=layers) > 0
    if mode == "distance" or (mode == "auto" and motion_size is not None):
        reach = settings.distance if mode == "distance" else settings.motion_multiple * float(motion_size)
        near = node_distances(mesh.points, seeds) <= reach
        inside |= eligible & near[mesh.quads].any(axis=1)
    elements = movable & (inside | structure)
    incidence = mesh.incidence
    touches_band = incidence.T @ elements.astype(float) > 0
    touches_outside = incidence.T @ (movable & ~elements).astype(float) > 0
    edge = np.flatnonzero(touches_band & touches_outside)
    band = Band(elements, edge, np.flatnonzero(touches_outside), reach, layers)
    log.info("mesh-motion band (%s): %d of %d movable quads, reach %s m, %s layers",
             mode, elements.sum(), movable.sum(), reach, layers)
    return band
