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


FIGURE_LABELS = {"min_skewness": "minimum skewness", "min_area_change": "minimum area change",
                 "max_area_change": "maximum area change", "wall_time_s": "wall time [s]"}


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def plot_sweep(path, rows: list[dict], keys: list[str], title: str = "") -> bool:
    """Line plots (one numeric key) or heat maps (two numeric keys) of a study.

    Keys with non-numeric values (e.g. the mover's name) make one series or
    panel each. Returns False when the study has no such shape to plot.
    """
    numeric = [k for k in keys if all(_is_number(r[k]) for r in rows)]
    series_keys = [k for k in keys if k not in numeric]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in series_keys), []).append(r)

    def label(group):
        return ", ".join(f"{k}={v}" for k, v in zip(series_keys, group)) or None

    if len(numeric) == 1:
        key = numeric[0]
        figures = ["min_skewness", "min_area_change", "max_area_change", "wall_time_s"]
        fig, axes = plt.subplots(1, 4, figsize=(16, 3.6), dpi=100)
        for group, sel in groups.items():
            x = [r[key] for r in sel]
            for ax, f in zip(axes, figures):
                ax.plot(x, [r.get(f, np.nan) for r in sel], "o-", ms=3, label=label(group))
        for ax, f in zip(axes, figures):
            ax.set_xlabel(key)
            ax.set_ylabel(FIGURE_LABELS[f])
            ax.grid(alpha=0.3)
            if len({r[key] for r in rows}) > 2 and min(r[key] for r in rows) > 0 and \
                    max(r[key] for r in rows) / min(r[key] for r in rows) > 100:
                ax.set_xscale("log")
        if series_keys:
            axes[0].legend(fontsize=7)
    elif len(numeric) == 2:
        kx, ky = numeric
        fig, axes = plt.subplots(1, len(groups), figsize=(5.5 * len(groups), 4.5), dpi=100, squeeze=False)
        for ax, (group, sel) in zip(axes[0], groups.items()):
            xs = sorted({r[kx] for r in sel})
            ys = sorted({r[ky] for r in sel})
            Z = np.full((len(ys), len(xs)), np.nan)
            for r in sel:
                Z[ys.index(r[ky]), xs.index(r[kx])] = r.get("min_skewness", np.nan)
            mesh = ax.pcolormesh(xs, ys, Z, shading="nearest", cmap="viridis")
            fig.colorbar(mesh, ax=ax, label="minimum skewness")
            if np.isfinite(Z).any():
                j, i = np.unravel_index(np.nanargmax(Z), Z.shape)
                ax.plot(xs[i], ys[j], "r*", ms=12)
                ax.set_title(f"{label(group) or ''}  best {Z[j, i]:.3f} at ({xs[i]:g}, {ys[j]:g})", fontsize=9)
            ax.set_xlabel(kx)
            ax.set_ylabel(ky)
    else:
        return False
    if title:
        fig.suptitle(title)
    save(fig, path)
    return True


def pareto(ax, rows: list[dict], x: str, y: str, label_key: str, title: str) -> None:
    """Cost-accuracy plot on log-log axes: ``y`` against ``x`` for each value of ``label_key``,
    joined in order of ``x``; rows with a true ``default`` are marked by a red star."""
    from itertools import groupby

    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter
    rows = sorted(rows, key=lambda r: str(r[label_key]))
    for label, group in groupby(rows, key=lambda r: str(r[label_key])):
        g = sorted(group, key=lambda r: r[x])
        ax.plot([r[x] for r in g], [max(r[y], 1e-16) for r in g], "o-", ms=4, label=label)
        for r in g:
            if r.get("default"):
                ax.plot(r[x], max(r[y], 1e-16), "r*", ms=14, zorder=5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))   # 0.1, 0.2, 0.5, 1, ...
    ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(x.replace("_", " "))
    ax.set_ylabel(y.replace("_", " "))
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)


def plot_nodal(path, points, quads, values, title="", label="", cmap="viridis", grey=None,
               outline=None, width=8.0) -> None:
    """A nodal field on quads (two Gouraud-shaded triangles each), solid elements in grey."""
    from matplotlib.tri import Triangulation
    span = np.ptp(points, axis=0)
    fig, ax = plt.subplots(figsize=(width, width * span[1] / span[0] + 0.6), dpi=110)
    tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    mesh = ax.tripcolor(Triangulation(points[:, 0], points[:, 1], tris), values, shading="gouraud", cmap=cmap)
    fig.colorbar(mesh, ax=ax, label=label, shrink=0.8)
    if grey is not None and np.any(grey):
        ax.add_collection(PolyCollection(points[quads[grey]], facecolors="0.6", edgecolors="none", alpha=0.85))
    if outline is not None and len(outline):
        ax.add_collection(LineCollection(points[outline], colors="red", linewidths=1.0))
    ax.set_aspect("equal")
    ax.set_title(title)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    save(fig, path)


def plot_design(path, points, quads, rho, speed=None, title="", width=8.0) -> None:
    """Design densities (grey: solid) over the flow speed (nodal, colour)."""
    from matplotlib.tri import Triangulation
    span = np.ptp(points, axis=0)
    fig, ax = plt.subplots(figsize=(width, width * span[1] / span[0] + 0.6), dpi=110)
    if speed is not None:
        tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        m = ax.tripcolor(Triangulation(points[:, 0], points[:, 1], tris), speed, shading="gouraud",
                         cmap="Blues")
        fig.colorbar(m, ax=ax, label="|v| [m/s]", shrink=0.8)
    colours = np.zeros((len(rho), 4))
    colours[:, 3] = np.clip(rho, 0, 1)                     # black, opaque where solid
    ax.add_collection(PolyCollection(points[quads], facecolors=colours, edgecolors="none"))
    ax.set_xlim(points[:, 0].min(), points[:, 0].max())
    ax.set_ylim(points[:, 1].min(), points[:, 1].max())
    ax.set_aspect("equal")
    ax.set_title(title)
    save(fig, path)


def plot_convergence(path, history: list[dict], title="") -> None:
    """Objective (log scale) and volume constraint versus iteration; stage starts dashed."""
    it = [h["iteration"] for h in history]
    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=110)
    objective = np.array([h["objective"] for h in history])
    ax.plot(it, np.abs(objective), "b-", label="objective")
    if np.all(objective > 0) and objective.max() / objective.min() > 20:
        ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("objective", color="b")
    ax2 = ax.twinx()
    ax2.plot(it, [h["constraint"] for h in history], "r-", label="constraint g")
    ax2.axhline(0.0, color="r", lw=0.5, ls=":")
    ax2.set_ylabel("volume constraint g (<= 0)", color="r")
    for k in range(1, len(history)):
        if history[k]["stage"] != history[k - 1]["stage"]:
            ax.axvline(history[k]["iteration"], color="0.7", lw=0.8, ls="--")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    save(fig, path)
