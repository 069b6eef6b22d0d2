"""Pictures with matplotlib (off-screen Agg backend): meshes and fields on quads."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402

from tofsi.output import atomic_write  # noqa: E402


def quad_field(ax, points, quads, values, cmap="viridis", vmin=None, vmax=None, edges=True,
               label=None):
    """Quads coloured by a per-element value, with a colour bar."""
    polys = PolyCollection(points[quads], array=np.asarray(values, dtype=float), cmap=cmap,
                           edgecolors="k" if edges else "face", linewidths=0.15 if edges else 0.0)
    polys.set_clim(vmin, vmax)
    ax.add_collection(polys)
    ax.set_xlim(points[:, 0].min(), points[:, 0].max())
    ax.set_ylim(points[:, 1].min(), points[:, 1].max())
    ax.set_aspect("equal")
    ax.figure.colorbar(polys, ax=ax, label=label, shrink=0.8)
    return polys


def save(fig, path) -> None:
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=fig.dpi, bbox_inches="tight", format="png"))
    plt.close(fig)


def plot_mesh(path, points, quads, values, interface_edges=None, title="", label="skewness",
              vmin=None, vmax=None, cmap="viridis", grey=None, width=7.0) -> None:
    """Mesh coloured by ``values`` (grey where ``grey`` is True), interface in red."""
    span = np.ptp(points, axis=0)
    fig, ax = plt.subplots(figsize=(width, width * span[1] / span[0] + 0.6), dpi=110)
    shown = np.ones(len(quads), bool) if grey is None else ~np.asarray(grey)
    if grey is not None and np.any(grey):
        ax.add_collection(PolyCollection(points[quads[grey]], facecolors="0.7",
                                         edgecolors="0.4", linewidths=0.15))
    quad_field(ax, points, quads[shown], np.asarray(values)[shown], cmap=cmap, vmin=vmin,
               vmax=vmax, label=label)
    if interface_edges is not None and len(interface_edges):
        ax.add_collection(LineCollection(points[interface_edges], colors="red", linewidths=1.2))
    ax.set_title(title)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    save(fig, path)
