"""Pictures with matplotlib (off-screen Agg backend): meshes and fields on quads, studies,
convergence.

Every picture is laid out by matplotlib's constrained layout, so panels,
colour bars and labels do not overlap; titles are figure titles wrapped to the
figure's width, so they never run under a colour bar. Axes carry units,
colour bars their quantity's name and what its scale means (skewness: 1
square corners, 0 degenerate, below 0 inverted), and every line, outline and
grey patch drawn over a field has an entry in the legend below the picture
(the fluid-structure interface, the design region, the solid, a failed element).
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.cm import ScalarMappable  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from tofsi.runs.output import atomic_write  # noqa: E402
from tofsi.mesh.quality import SKEWNESS_LABEL  # noqa: E402


@dataclass(frozen=True)
class Outline:
    """Lines drawn over a picture, with their legend entry: ``edges`` node pairs ``(m, 2)``
    of the picture's points."""

    edges: np.ndarray
    label: str
    color: str = "red"
    style: str = "-"
    width: float = 1.2


def element_boundary(quads: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Node pairs ``(m, 2)`` of the outline of the elements ``mask`` (their edges that no
    other element of the set shares)."""
    q = quads[np.asarray(mask, bool)]
    edges = np.sort(np.concatenate([q[:, [0, 1]], q[:, [1, 2]], q[:, [2, 3]], q[:, [3, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return unique[counts == 1]


def region_outlines(quads: np.ndarray, region: np.ndarray, solid: str = "fixed solid") -> list[Outline]:
    """The outlines of the design region (dashed) and of the fixed solid (named ``solid``) of a
    mesh with element tags ``region`` (:mod:`tofsi.mesh.structured`)."""
    from tofsi.mesh.structured import DESIGN, SOLID
    out = []
    if np.any(region == DESIGN):
        out.append(Outline(element_boundary(quads, region == DESIGN), "design region", "darkorange", "--"))
    if np.any(region == SOLID):
        out.append(Outline(element_boundary(quads, region == SOLID), solid, "red"))
    return out


def draw_outlines(ax, points, outlines) -> list:
    """Draw ``outlines`` over ``ax``; returns their legend handles."""
    handles = []
    for o in outlines:
        if len(o.edges):
            ax.add_collection(LineCollection(points[o.edges], colors=o.color, linewidths=o.width,
                                             linestyles=o.style, zorder=4))
            handles.append(Line2D([], [], color=o.color, lw=o.width, ls=o.style, label=o.label))
    return handles


def legend_below(fig, handles) -> None:
    """A legend for what is drawn over the fields, under the picture (never over the data)."""
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 3), fontsize=8,
                   frameon=False)

def field_figure(points, width: float = 7.0):
    """A figure for a field over the channel, its height following the domain's aspect."""
    span = np.ptp(points, axis=0)
    return plt.subplots(figsize=(width, width * span[1] / span[0] + 1.2), dpi=110, layout="constrained")


def set_title(fig, text: str, fontsize: float = 11) -> None:
    """The figure's title, wrapped to the figure's width (above every panel and colour bar)."""
    if text:
        chars = max(20, int(fig.get_figwidth() * 72 / (0.62 * fontsize)))
        fig.suptitle(textwrap.fill(text, chars), fontsize=fontsize)


def channel_axes(ax, points) -> None:
    ax.set_xlim(points[:, 0].min(), points[:, 0].max())
    ax.set_ylim(points[:, 1].min(), points[:, 1].max())
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def quad_field(ax, points, quads, values, cmap="viridis", vmin=None, vmax=None, edges=True,
               label=None):
    """Quads coloured by a per-element value, with a colour bar named ``label``."""
    polys = PolyCollection(points[quads], array=np.asarray(values, dtype=float), cmap=cmap,
                           edgecolors="k" if edges else "face", linewidths=0.15 if edges else 0.0)
    polys.set_clim(vmin, vmax)
    ax.add_collection(polys)
    channel_axes(ax, points)
    ax.figure.colorbar(polys, ax=ax, label=label, shrink=0.8)
    return polys


def save(fig, path) -> None:
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=fig.dpi, bbox_inches="tight", format="png"))
    plt.close(fig)


def plot_mesh(path, points, quads, values, interface_edges=None, title="", label=SKEWNESS_LABEL,
              vmin=None, vmax=None, cmap="viridis", grey=None, width=7.0, outlines=(),
              grey_label="solid") -> None:
    """Mesh coloured by ``values`` (grey where ``grey`` is True: ``grey_label`` in the legend),
    the fluid-structure interface in red, ``outlines`` (:class:`Outline`) over it."""
    fig, ax = field_figure(points, width)
    shown = np.ones(len(quads), bool) if grey is None else ~np.asarray(grey)
    handles = []
    if grey is not None and np.any(grey):
        ax.add_collection(PolyCollection(points[quads[grey]], facecolors="0.7",
                                         edgecolors="0.4", linewidths=0.15))
        handles.append(Patch(facecolor="0.7", edgecolor="0.4", label=grey_label))
    quad_field(ax, points, quads[shown], np.asarray(values)[shown], cmap=cmap, vmin=vmin,
               vmax=vmax, label=label)
    if interface_edges is not None:
        outlines = (Outline(np.asarray(interface_edges), "fluid-structure interface"), *outlines)
    handles += draw_outlines(ax, points, outlines)
    legend_below(fig, handles)
    set_title(fig, title)
    save(fig, path)


FIGURE_LABELS = {"min_skewness": "minimum skewness\n(1 square corners, < 0 inverted)",
                 "min_area_change": "minimum area change A / A0",
                 "max_area_change": "maximum area change A / A0", "wall_time_s": "wall time [s]"}


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def failed(row: dict) -> bool:
    """A study point that did not converge (its figures, if any, are the failed state's)."""
    return row.get("status") == "failed" or row.get("converged") is False


def _mark_failed(ax, xs, ys, label) -> None:
    """Red crosses at failed points; NaN values are marked on the bottom axis line."""
    ys = np.asarray(ys, dtype=float)
    finite = np.isfinite(ys)
    xs = np.asarray(xs, dtype=float)
    if finite.any():
        ax.plot(xs[finite], ys[finite], "x", color="red", ms=7, mew=1.5, label=label, zorder=5)
    if (~finite).any():
        ax.plot(xs[~finite], np.full((~finite).sum(), 0.02), "x", color="red", ms=7, mew=1.5,
                transform=ax.get_xaxis_transform(), clip_on=False,
                label=None if finite.any() else label, zorder=5)


def plot_sweep(path, rows: list[dict], keys: list[str], title: str = "") -> bool:
    """Line plots (one numeric key) or heat maps (two numeric keys) of a study.

    Keys with non-numeric values (e.g. the mover's name) make one series or
    panel each. Failed points (:func:`failed`) are red crosses, at the failed
    state's figures where they exist. Returns False when the study has no
    such shape to plot.
    """
    numeric = [k for k in keys if all(_is_number(r[k]) for r in rows)]
    series_keys = [k for k in keys if k not in numeric]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in series_keys), []).append(r)

    def label(group):
        return ", ".join(f"{k}={v}" for k, v in zip(series_keys, group, strict=True)) or None

    any_failed = any(failed(r) for r in rows)
    if len(numeric) == 1:
        key = numeric[0]
        figures = ["min_skewness", "min_area_change", "max_area_change", "wall_time_s"]
        fig, axes = plt.subplots(1, 4, figsize=(16, 4.0), dpi=100, layout="constrained")
        labelled = False
        for group, sel in groups.items():
            ok = [r for r in sel if not failed(r)]
            bad = [r for r in sel if failed(r)]
            for i, (ax, f) in enumerate(zip(axes, figures, strict=True)):
                ax.plot([r[key] for r in ok], [r.get(f, np.nan) for r in ok], "o-", ms=3, label=label(group))
                if bad:
                    _mark_failed(ax, [r[key] for r in bad], [r.get(f, np.nan) for r in bad],
                                 None if labelled or i else "failed")
            labelled = labelled or bool(bad)
        for ax, f in zip(axes, figures, strict=True):
            ax.set_xlabel(key)
            ax.set_ylabel(FIGURE_LABELS[f])
            ax.grid(alpha=0.3)
            values = [r[key] for r in rows]
            if len(set(values)) > 2 and min(values) > 0 and max(values) / min(values) > 100:
                ax.set_xscale("log")
        if series_keys or any_failed:
            axes[0].legend(fontsize=7)
    elif len(numeric) == 2:
        kx, ky = numeric
        fig, axes = plt.subplots(1, len(groups), figsize=(5.5 * len(groups), 5.0), dpi=100,
                                 squeeze=False, layout="constrained")
        for ax, (group, sel) in zip(axes[0], groups.items(), strict=True):
            xs = sorted({r[kx] for r in sel})
            ys = sorted({r[ky] for r in sel})
            Z = np.full((len(ys), len(xs)), np.nan)
            for r in sel:
                if not failed(r):
                    Z[ys.index(r[ky]), xs.index(r[kx])] = r.get("min_skewness", np.nan)
            mesh = ax.pcolormesh(xs, ys, Z, shading="nearest", cmap="viridis")
            fig.colorbar(mesh, ax=ax, label="minimum " + SKEWNESS_LABEL)
            bad = [r for r in sel if failed(r)]
            if bad:
                ax.plot([r[kx] for r in bad], [r[ky] for r in bad], "x", color="red", ms=8, mew=1.5,
                        label="failed")
            text = label(group) or ""
            if np.isfinite(Z).any():
                j, i = np.unravel_index(np.nanargmax(Z), Z.shape)
                ax.plot(xs[i], ys[j], "r*", ms=12, label="best")
                text += f"{'; ' if text else ''}best {Z[j, i]:.3f} at ({xs[i]:g}, {ys[j]:g})"
            if ax.get_legend_handles_labels()[0]:                 # below the map, off the data
                ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncols=2, frameon=False)
            ax.set_title(textwrap.fill(text, 45), fontsize=9)
            ax.set_xlabel(kx)
            ax.set_ylabel(ky)
    else:
        return False
    set_title(fig, title)
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
               outlines=(), width=8.0, grey_label="solid (density > 0.5)") -> None:
    """A nodal field on quads (two Gouraud-shaded triangles each), solid elements in grey
    (``grey_label`` in the legend), ``outlines`` (:class:`Outline`) over it."""
    from matplotlib.tri import Triangulation
    fig, ax = field_figure(points, width)
    tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    mesh = ax.tripcolor(Triangulation(points[:, 0], points[:, 1], tris), values, shading="gouraud", cmap=cmap)
    fig.colorbar(mesh, ax=ax, label=label, shrink=0.8)
    handles = []
    if grey is not None and np.any(grey):
        ax.add_collection(PolyCollection(points[quads[grey]], facecolors="0.6", edgecolors="none", alpha=0.85))
        handles.append(Patch(facecolor="0.6", alpha=0.85, label=grey_label))
    handles += draw_outlines(ax, points, outlines)
    legend_below(fig, handles)
    channel_axes(ax, points)
    set_title(fig, title)
    save(fig, path)


def plot_design(path, points, quads, rho, speed=None, title="", width=8.0, outlines=()) -> None:
    """Design densities (black: solid; colour bar ``density``) over the flow speed (nodal,
    blue; colour bar ``|v| [m/s]``), ``outlines`` (:class:`Outline`: the design region, the
    fixed solid) over both."""
    from matplotlib.tri import Triangulation
    fig, ax = field_figure(points, width)
    if speed is not None:
        tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        m = ax.tripcolor(Triangulation(points[:, 0], points[:, 1], tris), speed, shading="gouraud",
                         cmap="Blues")
        fig.colorbar(m, ax=ax, label="flow speed |v| [m/s]", shrink=0.8)
    colours = np.zeros((len(rho), 4))
    colours[:, 3] = np.clip(rho, 0, 1)                     # black, opaque where solid
    ax.add_collection(PolyCollection(points[quads], facecolors=colours, edgecolors="none"))
    fig.colorbar(ScalarMappable(Normalize(0.0, 1.0), "Greys"), ax=ax, shrink=0.8,
                 label="density rho (0 fluid, 1 solid)")
    legend_below(fig, draw_outlines(ax, points, outlines))
    channel_axes(ax, points)
    set_title(fig, title)
    save(fig, path)


def plot_convergence(path, history: list[dict], title="", objective_label="objective") -> None:
    """Objective (log scale when it spans decades) and volume constraint versus iteration;
    each continuation stage is labelled with its beta (and coupling) where it starts, the
    first one included, and a dashed line marks each new stage. When the fluid mesh moved
    (two-way stages), a second panel shows its quality per iteration: the smallest element
    skewness and the range of element area change. The legend names every line."""
    it = [h["iteration"] for h in history]
    skew = np.array([h.get("min_skewness", np.nan) for h in history], dtype=float)
    moved = bool(np.isfinite(skew).any())
    fig, axes = plt.subplots(2 if moved else 1, 1, figsize=(7.5, 6.6 if moved else 4.2), dpi=110,
                             layout="constrained", sharex=True, squeeze=False)
    ax = axes[0, 0]
    objective = np.array([h["objective"] for h in history])
    lines = ax.plot(it, np.abs(objective), "b-", label=objective_label)
    if np.all(objective > 0) and objective.max() / objective.min() > 20:
        ax.set_yscale("log")
    axes[-1, 0].set_xlabel("design iteration")
    ax.set_ylabel(objective_label, color="b")
    ax2 = ax.twinx()
    lines += ax2.plot(it, [h["constraint"] for h in history], "r-", label="volume constraint g")
    ax2.axhline(0.0, color="r", lw=0.5, ls=":")
    ax2.set_ylabel("volume constraint g (<= 0 feasible)", color="r")
    starts = [k for k in range(1, len(history)) if history[k]["stage"] != history[k - 1]["stage"]]
    for n, k in enumerate(starts):
        for row in axes[:, 0]:
            line = row.axvline(history[k]["iteration"], color="0.5", lw=0.8, ls="--",
                               label="new continuation stage" if n == 0 else None)
        if n == 0:
            lines.append(line)
    for k in ([0] if history else []) + starts:                  # every stage, the first too
        coupling = history[k].get("coupling", "")
        beta = history[k].get("beta")
        text = (f"beta {beta:g}" if beta is not None else f"stage {history[k]['stage']}") + (
            f", {coupling}" if coupling else "")
        ax.annotate(text, (history[k]["iteration"], 1.0), xycoords=("data", "axes fraction"), xytext=(2, -10),
                    textcoords="offset points", fontsize=7, color="0.35")
    if moved:
        q = axes[1, 0]
        lines += q.plot(it, skew, "g-", label="min element skewness")
        q.set_ylabel("min skewness (1 square corners,\n0 degenerate, < 0 inverted)", color="g")
        q.axhline(0.0, color="g", lw=0.5, ls=":")
        qa = q.twinx()
        lo = [h.get("min_area_change", np.nan) for h in history]
        hi = [h.get("max_area_change", np.nan) for h in history]
        lines += qa.plot(it, lo, "m--", lw=0.9, label="min area change A / A0")
        lines += qa.plot(it, hi, "m:", lw=0.9, label="max area change A / A0")
        qa.set_ylabel("element area change A / A0", color="m")
        q.grid(alpha=0.3)
        q.set_title("moved fluid mesh", fontsize=9)
    fig.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="outside lower center",
               ncols=min(len(lines), 3), frameon=False)
    ax.grid(alpha=0.3, which="both")
    set_title(fig, title)
    save(fig, path)
