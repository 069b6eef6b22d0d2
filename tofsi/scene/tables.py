"""The scene's own tables, registered in :data:`tofsi.core.registry.SCENE_TABLES`.

Each table is one :class:`SceneTable` entry: its frozen record (validated by
:func:`tofsi.core.config.build`), how it is built from the raw scene, how it is
written back as plain TOML/JSON values, the rows of the generated scene
reference (``docs/scenes.md``) and the keys a ``--resume`` may change. Scene
loading (:func:`tofsi.scene.scene.scene_from_dict`), the provenance record
(:func:`tofsi.runs.provenance.scene_tables`), the ``--resume`` check and the scene
reference walk this registry and, beside it, the tables of the registered fields
(:attr:`tofsi.fields.base.Field.tables`: ``[fluid]``, ``[structure]``, ``[mover]``, or a
table of your own field), both listed by :func:`tofsi.scene.scene.table_entries`.

Which mover moves the mesh is one setting, written either as
``effects.mesh_motion`` or as ``mover.name`` (``"none"`` switches mesh
motion off); both spellings address the same value.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Callable, Mapping

import movers
from tofsi.core.config import build, documentation, option
from tofsi.core.errors import InputError
from tofsi.core.registry import OBJECTIVES, SCENE_TABLES
from tofsi.mesh.structured import SIDES
from tofsi.scene.settings import CoupledSettings, DesignSettings, OptimizerSettings, SolverSettings, TuneSettings

THIN = 1e-6                 # solids thinner than this fraction of the channel get a warning
log = logging.getLogger(__name__)


def plain(value):
    """Tuples -> lists, mappings and records -> dicts, recursively (TOML and JSON shapes)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    return value


@dataclass(frozen=True)
class SceneTable:
    """One table of a scene file.

    name : the table's key (``"fluid"``); record : its frozen, validated record class;
    builder : ``(raw table, raw scene) -> record`` when the table needs more than
    :func:`~tofsi.core.config.build` (the mover: its name may come from ``effects``);
    writer : ``record -> plain table`` when ``dataclasses.asdict`` is not enough;
    reference : ``builtin -> rows (key, default, allowed, meaning)`` of the scene reference
    (``builtin``: of the registries' built-in entries only);
    resumable : keys of the table a ``--resume`` may change (they cannot change the
    replayed history);
    check : ``scene -> None``, raising an :class:`~tofsi.core.errors.InputError` for keys
    of the table that contradict other tables (run once every table is built).
    """

    name: str
    record: type
    builder: Callable[[Any, dict], Any] | None = None
    writer: Callable[[Any], dict] | None = None
    reference: Callable[[bool], list] | None = None
    resumable: tuple[str, ...] = ()
    check: Callable[[Any], None] | None = None

    def build(self, raw_scene: dict):
        """The record from the raw scene's table (defaults where the table is absent)."""
        raw = raw_scene.get(self.name, {})
        if self.builder is not None:
            return self.builder(raw, raw_scene)
        return build(self.record, raw, self.name)

    def write(self, record) -> dict:
        """The record as a plain table (``build`` of it gives the record back)."""
        return self.writer(record) if self.writer is not None else plain(record)

    def rows(self, builtin: bool = False) -> list:
        """Documentation rows ``(dotted key, default, allowed, meaning)`` (``builtin``: of the
        registries' built-in entries only, as ``docs/scenes.md`` shows them)."""
        if self.reference is not None:
            return self.reference(builtin)
        return documentation(self.record, self.name, builtin)


# ---- geometry, mesh, deformation, effects (and the mover's name), objectives ---------------------
@dataclass(frozen=True)
class Geometry:
    """A channel ``[0, length] x [0, height]`` with solid, hole and design rectangles and solid circles."""

    length: float = option(2.0, gt=0, doc="channel length along x [m]")
    height: float = option(1.0, gt=0, doc="channel height along y [m]")
    solids: tuple[tuple[float, ...], ...] = option((), length=4,
                                                   doc="solid rectangles [x0, x1, y0, y1] [m]; "
                                                       "overlapping ones merge into their union")
    holes: tuple[tuple[float, ...], ...] = option((), length=4,
                                                  doc="fluid rectangles cut out of the solids [m]; "
                                                      "each must overlap a solid")
    design: tuple[float, ...] = option((), doc="design rectangle [x0, x1, y0, y1] [m]; "
                                               "empty: no design region")
    circles: tuple[tuple[float, ...], ...] = option((), length=3,
                                                    doc="circular solids [x, y, r] [m]: the elements whose "
                                                        "centre lies inside (a staircase, symmetric about "
                                                        "the centre: the mesh has grid lines through it and "
                                                        "at x +- r, y +- r, and is graded towards the circle)")
    solid_names: tuple[str, ...] = option((), doc="names of the solid rectangles, one per entry of "
                                                  "geometry.solids (or none), for structure.clamped and "
                                                  "probes.forces")
    circle_names: tuple[str, ...] = option((), doc="names of the circles, one per entry of geometry.circles "
                                                   "(or none)")

    def __post_init__(self):
        if self.design and len(self.design) != 4:
            raise InputError("design", self.design, "expected [] or [x0, x1, y0, y1]")
        for i, (x, y, r) in enumerate(self.circles):
            if not (r > 0 and 0 <= x - r and x + r <= self.length and 0 <= y - r and y + r <= self.height):
                raise InputError(f"circles[{i}]", [x, y, r], f"need r > 0 and the circle inside the channel "
                                 f"(0 <= x - r, x + r <= {self.length}, 0 <= y - r, y + r <= {self.height})")
        for key, names, shapes in (("solid_names", self.solid_names, "solids"),
                                   ("circle_names", self.circle_names, "circles")):
            if names and len(names) != len(getattr(self, shapes)):
                raise InputError(key, list(names), f"give one name per entry of geometry.{shapes} "
                                 f"({len(getattr(self, shapes))}), or none")
        named = list(self.solid_names) + list(self.circle_names)
        for name in named:
            if not name or name in SIDES or named.count(name) > 1:
                raise InputError("solid_names" if name in self.solid_names else "circle_names", name,
                                 "a name must be non-empty, unique and not a channel side (" + ", ".join(SIDES) + ")")
        named = [("solids", i, r) for i, r in enumerate(self.solids)]
        named += [("holes", i, r) for i, r in enumerate(self.holes)]
        if self.design:
            named.append(("design", None, self.design))
        for name, i, (x0, x1, y0, y1) in named:
            key = name if i is None else f"{name}[{i}]"
            if not (0 <= x0 < x1 <= self.length and 0 <= y0 < y1 <= self.height):
                raise InputError(key, [x0, x1, y0, y1],
                                 f"need 0 <= x0 < x1 <= {self.length} and 0 <= y0 < y1 <= "
                                 f"{self.height} (inside the channel)")
        for i, hole in enumerate(self.holes):
            if not any(overlap(hole, solid) for solid in self.solids):
                raise InputError(f"holes[{i}]", list(hole), "lies outside every solid; a hole is "
                                 "cut out of a solid (geometry.solids)")
        for i, (x0, x1, y0, y1) in enumerate(self.solids):
            if x1 - x0 < THIN * self.length or y1 - y0 < THIN * self.height:
                log.warning("geometry.solids[%d] = %s is thinner than %g of the channel: its "
                            "elements will be that thin", i, [x0, x1, y0, y1], THIN)


def overlap(a, b) -> bool:
    """Rectangles ``[x0, x1, y0, y1]`` that share a positive area."""
    return min(a[1], b[1]) > max(a[0], b[0]) and min(a[3], b[3]) > max(a[2], b[2])


@dataclass(frozen=True)
class MeshSettings:
    """Graded structured mesh: fine at the structures, coarser away from them."""

    h_min: float = option(0.02, gt=0, doc="element size at the structures [m]")
    h_max: float = option(0.08, gt=0, doc="largest element size [m]")
    growth: float = option(1.15, ge=1, le=3, doc="size ratio of neighbouring elements away "
                                                 "from the structures (1: uniform h_min)")
    max_elements: int = option(2_000_000, ge=1, doc="refuse meshes with more elements")

    def __post_init__(self):
        if self.h_min > self.h_max:
            raise InputError("h_min", self.h_min, f"allowed: 0 < h_min <= h_max = {self.h_max}")


DEFORMATION_MODES = ("none", "translation", "rotation", "bending", "pressure", "fsi")


@dataclass(frozen=True)
class Deformation:
    """The structure's prescribed motion in a mesh-motion study."""

    mode: str = option("none", choices=DEFORMATION_MODES,
                       doc="translation/rotation/bending: rigid or U-shaped motion of the "
                           "solid; pressure: cantilever under uniform upstream pressure; "
                           "fsi: from the coupled fluid-structure solve")
    translation: float = option(0.2, doc="rigid motion in -y [m]")
    rotation_deg: float = option(30.0, ge=-180, le=180,
                                 doc="clockwise rotation about the solid's centroid [deg]")
    bending_tip: float = option(0.15, doc="downward motion of both tips of the U bending [m]")
    tip_displacement: float = option(0.15, gt=0,
                                     doc="largest structural displacement for pressure/fsi [m]")
    scale: bool = option(True, doc="fsi: scale the computed deformation to tip_displacement")


@dataclass(frozen=True)
class Effects:
    """Which physics a scene simulates; a disabled effect costs nothing."""

    fluid: str = option("none", choices=("navier-stokes", "stokes", "none"), doc="fluid model")
    structure: str = option("none", choices=("linear-elastic", "none"), doc="structure model")
    mesh_motion: str = option("none", doc="mover name, or none (same setting as mover.name)")
    coupling: str = option("one-way", choices=("one-way", "two-way"),
                           doc="two-way: the flow sees the deformed mesh")

    def __post_init__(self):
        names = movers.available()
        if self.mesh_motion != "none" and self.mesh_motion not in names:
            raise InputError("mesh_motion", self.mesh_motion,
                             "allowed: 'none' or one of " + ", ".join(map(repr, names)))


@dataclass(frozen=True)
class Probes:
    """What a solve reports besides its fields' figures (table ``[probes]``): the structure's
    displacement at named points and the fluid's force on named solids."""

    points: tuple[tuple[float, ...], ...] = option((), length=2,
                                                   doc="points [x, y] [m] where solve reports the structure's "
                                                       "displacement, as figures ux_<name> and uy_<name> [m] "
                                                       "(bilinear on the element holding the point)")
    point_names: tuple[str, ...] = option((), doc="the points' names, one per entry of probes.points (letters, "
                                                  "digits and _)")
    forces: tuple[str, ...] = option((), doc="named solids (geometry.solid_names, geometry.circle_names) whose "
                                             "drag and lift solve reports, as figures drag_<name> and "
                                             "lift_<name> [N/m]: the fluid load on their elements")

    def __post_init__(self):
        if len(self.point_names) != len(self.points):
            raise InputError("point_names", list(self.point_names), f"give one name per entry of probes.points "
                             f"({len(self.points)})")
        for name in self.point_names:
            if not name.isidentifier() or list(self.point_names).count(name) > 1:
                raise InputError("point_names", name, "a point's name is a word of letters, digits and _, "
                                 "used once")

    @property
    def named_points(self) -> dict[str, tuple[float, float]]:
        """The points by name."""
        return dict(zip(self.point_names, self.points, strict=True))


def _check_probes(scene) -> None:
    """The probes' points lie in the channel; their forces name named solids."""
    geometry = scene.geometry
    names = set(geometry.solid_names) | set(geometry.circle_names)
    for i, (x, y) in enumerate(scene.probes.points):
        if not (0 <= x <= geometry.length and 0 <= y <= geometry.height):
            raise InputError(f"probes.points[{i}]", [x, y], f"outside the channel [0, {geometry.length:g}] x "
                             f"[0, {geometry.height:g}]")
    for i, name in enumerate(scene.probes.forces):
        if name not in names:
            raise InputError(f"probes.forces[{i}]", name, "allowed: a named solid (" + (
                ", ".join(sorted(names)) or "none named: geometry.solid_names, geometry.circle_names") + ")")


def mover_name(raw: dict) -> str:
    """The mover a raw scene names, by ``mover.name`` or ``effects.mesh_motion`` (they must agree)."""
    by_effects = raw.get("effects", {}).get("mesh_motion") if isinstance(raw.get("effects"), dict) else None
    by_mover = raw.get("mover", {}).get("name") if isinstance(raw.get("mover"), dict) else None
    if by_effects is not None and by_mover is not None and by_effects != by_mover:
        raise InputError("mover.name", by_mover,
                         f"conflicts with effects.mesh_motion = {by_effects!r}; set one of them")
    name = by_mover if by_mover is not None else by_effects
    key = "mover.name" if by_mover is not None else "effects.mesh_motion"
    if name is not None and not isinstance(name, str):
        raise InputError(key, name, "expected a string")
    names = movers.available()
    if name is not None and name != "none" and name not in names:
        raise InputError(key, name, "allowed: 'none' or one of " + ", ".join(map(repr, names)))
    return "none" if name is None else name


@dataclass(frozen=True)
class ObjectiveSettings:
    """The objectives' parameters: an ``[objective.<name>]`` table for every objective with a
    parameter record (:attr:`tofsi.objectives.Objective.Params`)."""

    params: Mapping[str, Any] = dataclasses.field(default_factory=dict)


def _build_objectives(raw, raw_scene) -> ObjectiveSettings:
    """A record for every objective with parameters that loads (an objective plugin that fails
    to import is passed over unless the scene gives its table: then its error)."""
    if not isinstance(raw, dict):
        raise InputError("objective", raw, "expected a table")
    classes = {cls.name: cls for cls in OBJECTIVES if cls.Params is not None}
    for name, value in raw.items():
        if name not in OBJECTIVES:
            raise InputError(f"objective.{name}", value, "unknown key; allowed: a parameter table of one of "
                             + ", ".join(map(repr, sorted(classes))))
        if OBJECTIVES.get(name).Params is None:
            raise InputError(f"objective.{name}", value, "this objective has no parameters")
    return ObjectiveSettings(MappingProxyType({n: build(cls.Params, raw.get(n, {}), f"objective.{n}")
                                               for n, cls in classes.items()}))


def _write_objectives(settings: ObjectiveSettings) -> dict:
    return {name: plain(params) for name, params in settings.params.items()}


def _objective_rows(builtin: bool = False) -> list:
    names = OBJECTIVES.builtin() if builtin else [cls.name for cls in OBJECTIVES]
    rows = []
    for name in names:
        cls = OBJECTIVES.get(name)
        if cls.Params is not None:
            rows += documentation(cls.Params, f"objective.{name}", builtin)
    return rows


def _build_effects(raw, raw_scene) -> Effects:
    if not isinstance(raw, dict):
        raise InputError("effects", raw, "expected a table")
    return build(Effects, {**raw, "mesh_motion": mover_name(raw_scene)}, "effects")


for _table in (SceneTable("geometry", Geometry), SceneTable("mesh", MeshSettings),
               SceneTable("deformation", Deformation),
               SceneTable("effects", Effects, builder=_build_effects),
               SceneTable("design", DesignSettings),
               SceneTable("objective", ObjectiveSettings, builder=_build_objectives, writer=_write_objectives,
                          reference=_objective_rows),
               SceneTable("optimizer", OptimizerSettings, resumable=("max_iter", "output_every")),
               SceneTable("coupled", CoupledSettings), SceneTable("tune", TuneSettings),
               SceneTable("probes", Probes, check=_check_probes),
               SceneTable("solver", SolverSettings, resumable=("max_memory_gb",))):
    SCENE_TABLES.register(_table)
