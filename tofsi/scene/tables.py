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
from typing import Any, Callable, Mapping

import movers
from tofsi.core.config import build, documentation, option
from tofsi.core.errors import InputError
from tofsi.core.registry import SCENE_TABLES
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
    reference : ``() -> rows (key, default, allowed, meaning)`` of the scene reference;
    resumable : keys of the table a ``--resume`` may change (they cannot change the
    replayed history);
    check : ``scene -> None``, raising an :class:`~tofsi.core.errors.InputError` for keys
    of the table that contradict other tables (run once every table is built).
    """

    name: str
    record: type
    builder: Callable[[Any, dict], Any] | None = None
    writer: Callable[[Any], dict] | None = None
    reference: Callable[[], list] | None = None
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

    def rows(self) -> list:
        """Documentation rows ``(dotted key, default, allowed, meaning)``."""
        return self.reference() if self.reference is not None else documentation(self.record, self.name)


# ---- geometry, mesh, deformation, effects, mover --------------------------------------------
@dataclass(frozen=True)
class Geometry:
    """A channel ``[0, length] x [0, height]`` with solid, hole and design rectangles."""

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

    def __post_init__(self):
        if self.design and len(self.design) != 4:
            raise InputError("design", self.design, "expected [] or [x0, x1, y0, y1]")
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


def _build_effects(raw, raw_scene) -> Effects:
    if not isinstance(raw, dict):
        raise InputError("effects", raw, "expected a table")
    return build(Effects, {**raw, "mesh_motion": mover_name(raw_scene)}, "effects")


for _table in (SceneTable("geometry", Geometry), SceneTable("mesh", MeshSettings),
               SceneTable("deformation", Deformation),
               SceneTable("effects", Effects, builder=_build_effects),
               SceneTable("design", DesignSettings),
               SceneTable("optimizer", OptimizerSettings, resumable=("max_iter", "output_every")),
               SceneTable("coupled", CoupledSettings), SceneTable("tune", TuneSettings),
               SceneTable("solver", SolverSettings, resumable=("max_memory_gb",))):
    SCENE_TABLES.register(_table)
