"""Boundary conditions of the channel flow: walls, inflow, outflow and open outlets on any side.

Every side of the channel ``[0, L] x [0, H]`` is a no-slip wall except its
openings, segments ``[s0, s1]`` of the side (``s`` is y on the left and right
sides, x on the bottom and top):

* **inflow** ``[s0, s1, U]``: the parabolic normal velocity into the channel,
  ``v = U 4 (s - s0)(s1 - s) / (s1 - s0)^2 n_in``, tangential velocity 0;
* **outflow** ``[s0, s1, U]``: the same profile out of the channel;
* **open** ``[s0, s1]``: no Dirichlet condition, so the natural condition of
  the viscous form holds: ``mu dv/dn - p n = 0`` (gradient form, zero pressure
  for developed flow) or ``sigma n = 0`` (traction-free); with
  ``parallel_outflow`` the tangential velocity is 0 there (topFlow's outlets).
  With ``fluid.outlet = "fixed-pressure"`` the pressure is 0 at the segment's
  nodes instead, its end nodes included (their normal velocity free, unless
  another side's wall holds them): topFlow's and TOFLUX's outlets;
* **uniform** ``[s0, s1, vx, vy]``: the constant velocity ``(vx, vy)``, end nodes
  included (a free stream, topFlow's rugby ball; a moving wall).

Otherwise a segment's end points (and nodes within 1e-9 of the side's length
of them) belong to the wall. The scene describes openings in
``fluid.left/right/bottom/top``; without any, the channel of the older keys:
inflow over the whole left side with peak ``fluid.inlet_velocity`` (or the
segments ``fluid.inlets``) and the right side open (or the prescribed
segments ``fluid.outlets``). ``fluid.inlets``/``fluid.outlets`` always add
left inflow / right outflow segments.

Everything here is checked before any computation: segments inside their
side, not overlapping, holding mesh nodes, some inflow, and -- when nothing
is open -- prescribed inflow equal to outflow (incompressibility).

Velocities live on the element type's velocity nodes (Q2 for Taylor-Hood,
the corners for equal order; :mod:`tofsi.physics.fluid_elements`).

Pressure drop: the mean pressure over the inflow segments minus the mean
over the outflow and open segments, ``int p ds / int ds`` of the Q1
pressure along the side (exact for the piecewise-linear trace). The channel
boundary never moves (every mover keeps ``x = 0`` there), so the drop does
not depend on the mesh motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from tofsi.core.errors import InputError
from tofsi.mesh.structured import SIDES
from tofsi.physics.fluid_elements import TaylorHood

INWARD = {"left": (1.0, 0.0), "right": (-1.0, 0.0), "bottom": (0.0, 1.0), "top": (0.0, -1.0)}
KINDS = ("inflow", "outflow", "open", "uniform")


@dataclass(frozen=True)
class Opening:
    """A segment ``[start, end]`` of a side where the flow enters or leaves the channel."""

    side: str
    kind: str            # inflow, outflow, open, uniform
    start: float         # along the side [m]
    end: float
    peak: float = 0.0    # prescribed peak speed [m/s] (inflow/outflow)
    key: str = ""        # the scene key it came from (messages)
    velocity: tuple = (0.0, 0.0)     # the constant velocity of a uniform segment [m/s]

    def profile(self, s: np.ndarray) -> np.ndarray:
        """Parabolic speed ``4 U (s - s0)(s1 - s) / (s1 - s0)^2`` at positions ``s`` inside."""
        return 4.0 * self.peak * (s - self.start) * (self.end - s) / (self.end - self.start) ** 2


def side_coordinate(side: str, points: np.ndarray) -> np.ndarray:
    """Position along a side: y on the left and right sides, x on the bottom and top."""
    return points[:, 1] if side in ("left", "right") else points[:, 0]


def openings_from_settings(settings) -> list[Opening]:
    """The openings a :class:`~tofsi.scene.settings.FluidSettings` describes (see the module doc)."""
    out = [Opening("left", "inflow", y0, y1, U, f"fluid.inlets[{i}]") for i, (y0, y1, U) in enumerate(settings.inlets)]
    out += [Opening("right", "outflow", y0, y1, U, f"fluid.outlets[{i}]")
            for i, (y0, y1, U) in enumerate(settings.outlets)]
    for side in SIDES:
        table = getattr(settings, side)
        for kind in KINDS:
            for i, seg in enumerate(getattr(table, kind)):
                peak = seg[2] if kind in ("inflow", "outflow") else 0.0
                velocity = tuple(seg[2:4]) if kind == "uniform" else (0.0, 0.0)
                out.append(Opening(side, kind, seg[0], seg[1], peak, f"fluid.{side}.{kind}[{i}]", velocity))
    return out


def uses_side_tables(settings) -> bool:
    return any(not getattr(settings, side).is_empty for side in SIDES)


def channel_openings(mesh, settings) -> list[Opening]:
    """The openings of a scene's channel, with the older keys' defaults filled in."""
    openings = openings_from_settings(settings)
    if not uses_side_tables(settings):
        if not settings.inlets:
            openings.append(Opening("left", "inflow", mesh.ys[0], mesh.ys[-1], settings.inlet_velocity,
                                    "fluid.inlet_velocity"))
        if not settings.outlets:
            openings.append(Opening("right", "open", mesh.ys[0], mesh.ys[-1], 0.0, "fluid.outlet"))
    return openings


def segment_weights(mesh, side: str, start: float, end: float) -> np.ndarray:
    """Weights ``(n,)`` on the Q1 corner values giving ``int_start^end p ds`` along a side,
    exact for the piecewise-linear trace (the segment need not end on nodes)."""
    nodes = mesh.side_nodes(side)
    s = side_coordinate(side, mesh.points[nodes])
    a, b = s[:-1], s[1:]                                  # edges along the side
    c, d = np.maximum(a, start), np.minimum(b, end)       # their overlap with the segment
    part = np.maximum(d - c, 0.0)
    weights = np.zeros(mesh.n_nodes)
    np.add.at(weights, nodes[:-1], 0.5 * part * ((b - c) + (b - d)) / (b - a))
    np.add.at(weights, nodes[1:], 0.5 * part * ((c - a) + (d - a)) / (b - a))
    return weights


class FlowBoundary:
    """Dirichlet velocity dofs and values, and the openings, of a flow on a structured mesh.

    Velocity dofs are ``2 k + i`` on the velocity nodes ``k`` of ``element`` (a record of
    :mod:`tofsi.physics.fluid_elements`; Taylor-Hood by default); ``fixed`` lists the
    fixed ones, ``values`` holds their prescribed values (0 elsewhere), and
    ``fixed_pressure`` the corner nodes where the pressure is 0 (``fixed_pressure_outlets``).
    """

    def __init__(self, mesh, openings, parallel_outflow: bool = False, element=TaylorHood,
                 fixed_pressure_outlets: bool = False):
        self.mesh, self.element = mesh, element
        self.openings = tuple(openings)
        self._check_positions()
        nv = element.n_nodes(mesh)
        Pv = element.points(mesh)
        fixed = np.zeros((nv, 2), dtype=bool)
        values = np.zeros((nv, 2))
        free_on = {side: np.zeros(nv, dtype=bool) for side in SIDES}    # open, per side
        pressure = []
        for o in self.openings:
            nodes = element.side_nodes(mesh, o.side)
            s = side_coordinate(o.side, Pv[nodes])
            tol = 1e-9 * (s[-1] - s[0])                         # nodes at the ends are the wall's
            closed = o.kind == "uniform" or (o.kind == "open" and fixed_pressure_outlets)
            ends = -tol if closed else tol                      # ... unless the segment holds them
            inside = nodes[(s > o.start + ends) & (s < o.end - ends)]
            if inside.size == 0:
                raise InputError(o.key, [o.start, o.end], "holds no mesh node: widen it or refine the mesh")
            if o.kind == "open":
                free_on[o.side][inside] = True
                if fixed_pressure_outlets:
                    corners = mesh.side_nodes(o.side)
                    c = side_coordinate(o.side, mesh.points[corners])
                    pressure.append(corners[(c > o.start - tol) & (c < o.end + tol)])
            elif o.kind == "uniform":
                fixed[inside] = True
                values[inside] = o.velocity
            else:
                sign = 1.0 if o.kind == "inflow" else -1.0
                values[inside] = sign * o.profile(side_coordinate(o.side, Pv[inside]))[:, None] * INWARD[o.side]
        for side in SIDES:                       # a wall node is fixed by any side it lies on
            nodes = element.side_nodes(mesh, side)
            fixed[nodes[~free_on[side][nodes]]] = True
        if parallel_outflow:                      # tangential component of open segments fixed to 0
            for side in SIDES:
                tangential = 1 if side in ("left", "right") else 0
                fixed[np.flatnonzero(free_on[side]), tangential] = True
        self.fixed = np.flatnonzero(fixed.ravel())
        self.values = np.where(fixed, values, 0.0).ravel()
        self.fixed_pressure = np.unique(np.concatenate(pressure)) if pressure else np.zeros(0, dtype=np.int64)
        self.is_open = any(o.kind == "open" for o in self.openings)
        self._check_flows()

    @classmethod
    def for_channel(cls, mesh, settings, element=TaylorHood) -> "FlowBoundary":
        """The boundary a scene's ``[fluid]`` table describes."""
        return cls(mesh, channel_openings(mesh, settings), settings.parallel_outflow, element,
                   settings.outlet == "fixed-pressure")

    @classmethod
    def prescribed(cls, mesh, velocity, element=TaylorHood) -> "FlowBoundary":
        """A closed box with ``velocity(points (m, 2)) -> (m, 2)`` on all four sides (verification)."""
        self = object.__new__(cls)
        self.mesh, self.element, self.openings, self.is_open = mesh, element, (), False
        nodes = np.unique(np.concatenate([element.side_nodes(mesh, side) for side in SIDES]))
        values = np.zeros((element.n_nodes(mesh), 2))
        values[nodes] = velocity(element.points(mesh)[nodes])
        self.fixed = np.sort(np.concatenate([2 * nodes, 2 * nodes + 1]))
        self.values = values.ravel()
        self.fixed_pressure = np.zeros(0, dtype=np.int64)
        return self

    # ---- checks -------------------------------------------------------------------------
    def _check_positions(self) -> None:
        m = self.mesh
        extent = {"left": m.ys, "right": m.ys, "bottom": m.xs, "top": m.xs}
        for o in self.openings:
            lo, hi = extent[o.side][0], extent[o.side][-1]
            if not (lo <= o.start < o.end <= hi):
                raise InputError(o.key, [o.start, o.end], f"need {lo:g} <= from < to <= {hi:g} (along the "
                                                          f"{o.side} side)")
        for side in SIDES:
            segs = sorted((o for o in self.openings if o.side == side), key=lambda o: o.start)
            for a, b in pairwise(segs):
                if b.start < a.end:
                    raise InputError(b.key, [b.start, b.end], f"overlaps {a.key} = {[a.start, a.end]}")
        if not any(o.kind in ("inflow", "uniform") for o in self.openings):
            raise InputError("fluid", "no inflow", "list an inflow segment (fluid.<side>.inflow or fluid.inlets)")

    def side_flux(self, side: str, inward=None) -> float:
        """Volume flow [m^2/s] into the channel through ``side`` of the discrete boundary values
        (``inward``: a bool mask on the side's nodes to count, default all), integrated exactly
        for the element's trace (trapezoids on Q1 edges, Simpson's rule on Q2 edges)."""
        nodes = self.element.side_nodes(self.mesh, side)        # corner, (mid,) corner, ... along the side
        s = side_coordinate(side, self.element.points(self.mesh)[nodes])
        vn = self.values.reshape(-1, 2)[nodes] @ np.array(INWARD[side])
        if inward is not None:
            vn = np.where(inward, vn, 0.0)
        if self.element.degree == 1:
            return float(np.sum((s[1:] - s[:-1]) * (vn[1:] + vn[:-1]) / 2.0))
        a, mid, b = vn[:-2:2], vn[1:-1:2], vn[2::2]
        return float(np.sum((s[2::2] - s[:-2:2]) * (a + 4 * mid + b) / 6.0))

    def flux(self, kind: str) -> float:
        """Volume flow [m^2/s] through the segments of ``kind`` (inflow: into, outflow: out of the
        channel) of the discrete boundary values."""
        total = 0.0
        for o in self.openings:
            if o.kind != kind:
                continue
            nodes = self.element.side_nodes(self.mesh, o.side)
            s = side_coordinate(o.side, self.element.points(self.mesh)[nodes])
            q = self.side_flux(o.side, (s >= o.start) & (s <= o.end))       # this segment's nodes only
            total += q if kind == "inflow" else -q
        return total

    def _check_flows(self) -> None:
        if not np.any(self.values):
            raise InputError("fluid", "no inflow", "every prescribed segment has zero velocity")
        if not self.is_open:
            net = sum(self.side_flux(side) for side in SIDES)
            q_in, q_out = self.flux("inflow"), self.flux("outflow")
            if abs(net) > 1e-9 * max(q_in, q_out, max(abs(self.side_flux(side)) for side in SIDES)):
                raise InputError("fluid", f"inflow {q_in:.6g} m^2/s, outflow {q_out:.6g} m^2/s, net {net:.6g} m^2/s",
                                 "with no open segment the prescribed flows must balance (incompressible); "
                                 "open a segment or change a peak")

    # ---- pressure ---------------------------------------------------------------------
    def mean_pressure_weights(self, kinds) -> np.ndarray:
        """Weights ``(n,)`` on the Q1 corner pressures giving the mean pressure over the
        openings of ``kinds``: ``sum int_seg p ds / sum |seg|``."""
        weights = np.zeros(self.mesh.n_nodes)
        length = 0.0
        for o in self.openings:
            if o.kind in kinds:
                weights += segment_weights(self.mesh, o.side, o.start, o.end)
                length += o.end - o.start
        return weights / length if length else weights

    @property
    def has_pressure_drop(self) -> bool:
        return any(o.kind == "inflow" for o in self.openings) and any(o.kind != "inflow" for o in self.openings)

    def pressure_drop_weights(self) -> np.ndarray:
        """``d(pressure drop)/dp`` on the Q1 corner pressures (n,)."""
        return self.mean_pressure_weights(("inflow",)) - self.mean_pressure_weights(("outflow", "open"))
