"""Scenes: a channel with structures, a mesh, effects, a mover and settings.

A scene is a TOML file (see ``examples/scenes/``) loaded into a frozen,
validated :class:`Scene`. ``--set KEY=VALUE`` overrides are applied to the
raw tables before validation, so they are checked exactly like the file.

Which mover moves the mesh is one setting, written either as
``effects.mesh_motion`` or as ``mover.name`` (``"none"`` switches mesh
motion off); both spellings address the same value.
"""

from __future__ import annotations

import dataclasses
import logging
import tomllib
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import movers
from tofsi.config import build, coerce, option
from tofsi.errors import InputError
from tofsi.settings import (BandSettings, CoupledSettings, DesignSettings, FluidSettings,
                            OptimizerSettings, SolverSettings, StructureSettings, TuneSettings)

THIN = 1e-6                 # solids thinner than this fraction of the channel get a warning
MIN_ELEMENTS_ACROSS = 4     # mesh.h_max is at most the channel's smaller side over this
log = logging.getLogger(__name__)


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


@dataclass(frozen=True)
class MoverSettings:
    """The mover and its parameters (``[mover]`` plus ``[mover.<name>]`` tables)."""

    name: str
    layers: tuple[float, ...] = ()
    params: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    layers_from: str = "density"
    band: BandSettings = dataclasses.field(default_factory=BandSettings)

    @property
    def options(self):
        """The selected mover's parameter record (None when mesh motion is off)."""
        return self.params.get(self.name)


@dataclass(frozen=True)
class Scene:
    """A validated, frozen scene."""

    name: str
    description: str
    geometry: Geometry
    mesh: MeshSettings
    deformation: Deformation
    effects: Effects
    mover: MoverSettings
    fluid: FluidSettings
    structure: StructureSettings
    design: DesignSettings
    optimizer: OptimizerSettings
    coupled: CoupledSettings
    tune: TuneSettings = dataclasses.field(default_factory=TuneSettings)
    source: str = ""
    solver: SolverSettings = dataclasses.field(default_factory=SolverSettings)

    @property
    def has_design(self) -> bool:
        return bool(self.geometry.design)


_TABLES = {"geometry": Geometry, "mesh": MeshSettings, "deformation": Deformation,
           "fluid": FluidSettings, "structure": StructureSettings, "design": DesignSettings,
           "optimizer": OptimizerSettings, "coupled": CoupledSettings,
           "solver": SolverSettings, "tune": TuneSettings}
_TOP = {"name", "description", "effects", "mover", *_TABLES}


LAYERS_FROM = ("density", "solid")


def _build_mover(raw: dict, mover_name: str) -> MoverSettings:
    names = movers.available()
    raw = dict(raw)
    layers = raw.pop("layers", [])
    layers_from = coerce(str, raw.pop("layers_from", "density"), "mover.layers_from",
                         dict(choices=LAYERS_FROM))
    band = build(BandSettings, raw.pop("band", {}), "mover.band")
    for key, value in raw.items():
        if key not in names:
            raise InputError(f"mover.{key}", value, "unknown key; allowed: name, layers, layers_from, "
                             "band, or a "
                             "parameter table of one of " + ", ".join(map(repr, names)))
    factors = coerce(tuple[float, ...], layers, "mover.layers",
                     dict(gt=0, doc="stiffening factor per element layer"))
    params = {n: build(movers.mover_class(n).Params, raw.get(n, {}), f"mover.{n}") for n in names}
    return MoverSettings(name=mover_name, layers=factors, params=MappingProxyType(params),
                         layers_from=layers_from, band=band)


def _mover_name(raw: dict) -> str:
    by_effects = raw.get("effects", {}).get("mesh_motion") if isinstance(raw.get("effects"), dict) else None
    by_mover = raw.get("mover", {}).get("name") if isinstance(raw.get("mover"), dict) else None
    if by_effects is not None and by_mover is not None and by_effects != by_mover:
        raise InputError("mover.name", by_mover,
                         f"conflicts with effects.mesh_motion = {by_effects!r}; set one of them")
    name = by_mover if by_mover is not None else by_effects
    key = "mover.name" if by_mover is not None else "effects.mesh_motion"
    names = movers.available()
    if name is not None and name != "none" and name not in names:
        raise InputError(key, name, "allowed: 'none' or one of " + ", ".join(map(repr, names)))
    return "none" if name is None else name


ALIASES = {("structure", "simp_penalty"): ("design", "penalty"),
           ("fluid", "brinkman_q"): ("design", "brinkman_q")}
"""Old keys of a value that now has one key: the first entry of a continuation schedule."""


def _resolve_aliases(raw: dict) -> dict:
    """``raw`` with each old key moved to its schedule (a warning names the new key; a
    conflicting value is an input error)."""
    raw = dict(raw)
    for (table, key), (to_table, to_key) in ALIASES.items():
        if not isinstance(raw.get(table), dict) or key not in raw[table]:
            continue
        raw[table] = dict(raw[table])
        value = raw[table].pop(key)
        warnings.warn(f"{table}.{key} is an old name: the value is the first entry of "
                      f"{to_table}.{to_key} (write {to_table}.{to_key} = [{value}])", FutureWarning,
                      stacklevel=3)
        target = dict(raw.get(to_table) or {}) if isinstance(raw.get(to_table, {}), dict) else None
        if target is None:
            continue                                    # a malformed table: reported by its build
        if to_key in target:
            schedule = target[to_key]
            first = schedule[0] if isinstance(schedule, (list, tuple)) and schedule else schedule
            if first != value:
                raise InputError(f"{table}.{key}", value, f"conflicts with {to_table}.{to_key} = "
                                 f"{schedule!r}: the old key is that schedule's first entry; set one of them")
        else:
            target[to_key] = [value]
        raw[to_table] = target
    return raw


def scene_from_dict(raw: dict, source: str = "") -> Scene:
    """Validate raw tables (as read from TOML) into a :class:`Scene`."""
    if not isinstance(raw, dict):
        raise InputError("scene", raw, "expected a table")
    raw = _resolve_aliases(raw)
    for key in raw:
        if key not in _TOP:
            raise InputError(key, raw[key], "unknown key; allowed keys: " + ", ".join(sorted(_TOP)))
    name = raw.get("name")
    if not isinstance(name, str) or not name or any(c in name for c in "/\\\0") or name in (".", ".."):
        raise InputError("name", name, "required: a non-empty string without slashes, not '.' or '..' "
                         "(it names the output folder)")
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise InputError("description", description, "expected a string")
    mover_name = _mover_name(raw)
    if not isinstance(mover_name, str):
        raise InputError("mover.name", mover_name, "expected a string")
    effects_raw = dict(raw.get("effects", {}) or {})
    effects_raw["mesh_motion"] = mover_name
    mover_raw = raw.get("mover", {})
    if not isinstance(mover_raw, dict):
        raise InputError("mover", mover_raw, "expected a table")
    mover_raw = {k: v for k, v in mover_raw.items() if k != "name"}
    tables = {key: build(cls, raw.get(key, {}), key) for key, cls in _TABLES.items()}
    effects = build(Effects, effects_raw, "effects")
    mover = _build_mover(mover_raw, mover_name)
    _check_across_tables(tables["geometry"], tables["mesh"], tables["fluid"])
    two_way = effects.coupling == "two-way" and effects.mesh_motion != "none"
    if "two-way" in tables["design"].coupling and not two_way:
        raise InputError("design.coupling", list(tables["design"].coupling),
                         "two-way stages need effects.coupling = \"two-way\" and a mover (mover.name)")
    return Scene(name=name, description=description, effects=effects, mover=mover,
                 source=source, **tables)


def _check_across_tables(geometry: Geometry, mesh: MeshSettings, fluid) -> None:
    """Keys checked against the channel: element sizes, inflow and outflow segments."""
    smaller = min(geometry.length, geometry.height)
    if mesh.h_max > smaller / MIN_ELEMENTS_ACROSS:
        raise InputError("mesh.h_max", mesh.h_max, f"allowed: h_max <= {smaller / MIN_ELEMENTS_ACROSS:g} "
                         f"(at least {MIN_ELEMENTS_ACROSS} elements across the channel's smaller "
                         f"side, {smaller:g} m)")
    for name, side in (("inlets", "left"), ("outlets", "right")):
        for i, (y0, y1, _) in enumerate(getattr(fluid, name)):
            if y0 < 0 or y1 > geometry.height:
                raise InputError(f"fluid.{name}[{i}]", [y0, y1], f"extends outside the channel's "
                                 f"{side} side; need 0 <= y0 < y1 <= geometry.height = {geometry.height:g}")


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"mover.yeoh.A20=1e3"`` -> (["mover", "yeoh", "A20"], 1000.0); values are TOML."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise InputError("--set", text, "expected KEY=VALUE with a dotted KEY, e.g. mover.name=spring")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()                          # bare words are strings
    return key.split("."), parsed


def apply_overrides(raw: dict, overrides) -> dict:
    """A copy of ``raw`` with each ``KEY=VALUE`` (or ``(path, value)``) applied."""
    import copy
    raw = copy.deepcopy(raw)
    for item in overrides or ():
        path, value = parse_override(item) if isinstance(item, str) else item
        if list(path) in (["mover", "name"], ["effects", "mesh_motion"]):
            for alias in (["mover", "name"], ["effects", "mesh_motion"]):
                if isinstance(raw.get(alias[0]), dict):
                    raw[alias[0]].pop(alias[1], None)
        table = raw
        for part in path[:-1]:
            nxt = table.setdefault(part, {})
            if not isinstance(nxt, dict):
                raise InputError(".".join(path), value, f"{part} is not a table")
            table = nxt
        table[path[-1]] = value
    return raw


def read_scene_file(path: str | Path) -> dict:
    """Raw tables of a scene file, with clear errors for missing or malformed files."""
    path = Path(path)
    if path.is_dir():
        raise InputError("scene", str(path), "is a directory; give a scene file (TOML)")
    if not path.is_file():
        raise InputError("scene", str(path), "no such file")
    try:
        text = path.read_bytes().decode("utf-8-sig")          # a byte-order mark is allowed
        return tomllib.loads(text)
    except PermissionError:
        raise InputError("scene", str(path), "file is not readable") from None
    except UnicodeDecodeError:
        raise InputError("scene", str(path), "not a text file (UTF-8 TOML expected)") from None
    except tomllib.TOMLDecodeError as err:
        raise InputError("scene", str(path), f"not valid TOML ({err})") from None


def load_scene(path: str | Path, overrides=None) -> Scene:
    """Load, override and validate a scene file.

    overrides : iterable of ``"dotted.key=value"`` strings (TOML values)
    """
    raw = apply_overrides(read_scene_file(path), overrides)
    return scene_from_dict(raw, source=str(path))


def reference_table() -> str:
    """Markdown table of every scene key: default, allowed values, meaning (docs/scenes.md)."""
    from tofsi.config import documentation
    rows = [("name", "(required)", "a string without slashes, not . or ..", "the scene's name (output folder)"),
            ("description", "", "a string", "one line about the scene"),
            ("mover.name", "none", "none, " + ", ".join(movers.available()),
             "the mover (same setting as effects.mesh_motion)"),
            ("mover.layers", [], "list of numbers, each 0 < value",
             "stiffening factor of each element layer counted from the interface"),
            ("mover.layers_from", "density", "one of 'density', 'solid'",
             "design scenes: count the layers from the evolving design (smooth dilation of the "
             "densities, gray elements partly stiffened, differentiable) or from the fixed solid only")]
    for key, cls in _TABLES.items():
        rows += documentation(cls, key)
    rows += [r for r in documentation(Effects, "effects")]
    rows += documentation(BandSettings, "mover.band")
    for name in movers.available():
        rows += documentation(movers.mover_class(name).Params, f"mover.{name}")

    def show(value):
        if isinstance(value, tuple):
            return "[" + ", ".join(show(v) for v in value) + "]"
        if isinstance(value, bool):
            return str(value).lower()
        return f'"{value}"' if isinstance(value, str) and value != "(required)" else str(value)
    lines = ["| key | default | allowed | meaning |", "|---|---|---|---|"]
    lines += [f"| `{k}` | {show(d)} | {a} | {doc} |".replace("|  |", "| |") for k, d, a, doc in rows]
    return "\n".join(lines) + "\n"
