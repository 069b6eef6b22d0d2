"""Scenes: a channel with structures, a mesh, effects, a mover and settings.

A scene is a TOML file (see ``examples/scenes/``) loaded into a frozen,
validated :class:`Scene`. ``--set KEY=VALUE`` overrides are applied to the
raw tables before validation, so they are checked exactly like the file.
The tables a scene may hold are the entries of
:data:`tofsi.core.registry.SCENE_TABLES` (:mod:`tofsi.scene.tables`) and the
tables of the registered fields (:data:`tofsi.core.registry.FIELDS`), as the
``[mover.<name>]`` tables are those of the registered movers; loading,
provenance, ``--resume`` and the scene reference (:func:`reference_table`)
all read that one list, :func:`table_entries`.
"""

from __future__ import annotations

import re
import tomllib
import unicodedata
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from tofsi.core.errors import InputError
from tofsi.core.registry import FIELDS, OBJECTIVES, SCENE_TABLES

MIN_ELEMENTS_ACROSS = 4     # mesh.h_max is at most the channel's smaller side over this
MOVER_ALIASES = (("mover", "name"), ("effects", "mesh_motion"))      # one setting, two spellings
_INDEXED = re.compile(r"^(?P<key>[^\[\]]+)(?P<indices>(\[\d+\])+)$")     # layers[0], solids[1][2]


def table_entries() -> list:
    """Every table a scene holds (:class:`~tofsi.scene.tables.SceneTable` entries), in file
    order: the scene's own, with each registered field's tables after ``[effects]`` (which
    switches the fields on), in the fields' order."""
    own = list(SCENE_TABLES)
    names = [table.name for table in own]
    at = names.index("effects") + 1 if "effects" in names else len(own)
    entries: dict = {}
    for table in [*own[:at], *(table for field in FIELDS for table in field.tables), *own[at:]]:
        if entries.setdefault(table.name, table) is not table:
            raise ValueError(f"two scene tables are named {table.name!r}")
    return list(entries.values())


@dataclass(frozen=True)
class Scene:
    """A validated, frozen scene: its name, description and one record per table
    (:func:`table_entries`), read as attributes (``scene.fluid``,
    ``scene.design``, ``scene.mover``, ...; a registered table ``"toy"`` is ``scene.toy``)."""

    name: str
    description: str
    tables: Mapping[str, Any]
    source: str = ""

    def __getattr__(self, key: str):
        tables = self.__dict__.get("tables")           # absent while unpickling
        if tables is not None and key in tables:
            return tables[key]
        raise AttributeError(f"{type(self).__name__!r} has no table or attribute {key!r}")

    def __eq__(self, other) -> bool:
        return (isinstance(other, Scene) and (self.name, self.description, self.source)
                == (other.name, other.description, other.source) and dict(self.tables) == dict(other.tables))

    def __hash__(self) -> int:
        return hash((self.name, self.description, self.source, tuple(self.tables)))

    def __reduce__(self):                               # a read-only mapping does not pickle
        return (_rebuild, (self.name, self.description, dict(self.tables), self.source))

    @property
    def has_design(self) -> bool:
        return bool(self.geometry.design)

    def with_tables(self, **records) -> "Scene":
        """The same scene with some tables' records replaced (records are validated on
        construction; the checks across tables run again)."""
        unknown = set(records) - set(self.tables)
        if unknown:
            raise ValueError(f"no such scene tables: {sorted(unknown)}")
        scene = Scene(self.name, self.description, MappingProxyType({**self.tables, **records}), self.source)
        _check_across_tables(scene)
        return scene


def _rebuild(name, description, tables, source) -> Scene:
    return Scene(name, description, MappingProxyType(tables), source)


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
    """Validate raw tables (as read from TOML) into a :class:`Scene`: every registered table
    (absent ones at their defaults), then the checks across tables."""
    if not isinstance(raw, dict):
        raise InputError("scene", raw, "expected a table")
    raw = _resolve_aliases(raw)
    entries = table_entries()
    top = ("name", "description", *(table.name for table in entries))
    for key in raw:
        if key not in top:
            raise InputError(key, raw[key], "unknown key; allowed keys: " + ", ".join(sorted(top)))
    name = raw.get("name")
    if (not isinstance(name, str) or not name or any(c in name for c in "/\\")
            or any(unicodedata.category(c) == "Cc" for c in name) or name in (".", "..")):
        raise InputError("name", name, "required: a non-empty string without slashes or control "
                         "characters (newline, tab, ...), not '.' or '..' (it names the output folder)")
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise InputError("description", description, "expected a string")
    tables = {table.name: table.build(raw) for table in entries}
    scene = Scene(name=name, description=description, tables=MappingProxyType(tables), source=source)
    _check_across_tables(scene)
    return scene


def _check_across_tables(scene: Scene) -> None:
    """Keys checked against each other: element sizes against the channel, each table's own
    checks (:attr:`~tofsi.scene.tables.SceneTable.check`: the flow's openings against the
    channel), the two-way stages against the effects, the objective against the effect it needs."""
    geometry, mesh = scene.geometry, scene.mesh
    smaller = min(geometry.length, geometry.height)
    if mesh.h_max > smaller / MIN_ELEMENTS_ACROSS:
        raise InputError("mesh.h_max", mesh.h_max, f"allowed: h_max <= {smaller / MIN_ELEMENTS_ACROSS:g} "
                         f"(at least {MIN_ELEMENTS_ACROSS} elements across the channel's smaller "
                         f"side, {smaller:g} m)")
    for table in table_entries():
        if table.check is not None:
            table.check(scene)
    effects = scene.effects
    two_way = effects.coupling == "two-way" and effects.mesh_motion != "none"
    if "two-way" in scene.design.coupling and not two_way:
        raise InputError("design.coupling", list(scene.design.coupling),
                         "two-way stages need effects.coupling = \"two-way\" and a mover (mover.name)")
    if scene.design.structure_model and effects.structure == "none":
        raise InputError("design.structure_model", list(scene.design.structure_model),
                         "a structure model per stage needs a structure (effects.structure)")
    if scene.optimizer.algorithm == "OC" and scene.design.min_skewness > -1:
        raise InputError("optimizer.algorithm", "OC", "MMA or CCSAQ with design.min_skewness (the "
                         "optimality-criteria update handles one volume bound only)")
    if scene.has_design:
        needs = OBJECTIVES.get(scene.design.objective).needs       # the effect it is a figure of
        if getattr(effects, needs) == "none":
            raise InputError("design.objective", scene.design.objective, f"needs effects.{needs}")


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
    """A copy of ``raw`` with each ``KEY=VALUE`` (or ``(path, value)``) applied.

    ``KEY[i]=VALUE`` replaces entry ``i`` of a list the scene holds (``mover.layers[0]=2``;
    ``[i][j]`` for a list of lists). ``mover.name`` and ``effects.mesh_motion`` are one
    setting: an override of either replaces the file's value of both, and two overrides
    giving them different values are refused.
    """
    import copy
    raw = copy.deepcopy(raw)
    movers_set: dict[tuple, tuple[str, object]] = {}        # alias -> (override text, value)
    for item in overrides or ():
        path, value = parse_override(item) if isinstance(item, str) else item
        path = list(path)
        shown = item if isinstance(item, str) else f"{'.'.join(path)}={value!r}"
        if tuple(path) in MOVER_ALIASES:
            other = [a for a in MOVER_ALIASES if a != tuple(path)][0]
            if other in movers_set and movers_set[other][1] != value:
                raise InputError(".".join(path), value, f"conflicts with --set {movers_set[other][0]}: "
                                 "mover.name and effects.mesh_motion are one setting; give one of them")
            movers_set[tuple(path)] = (shown, value)
            for alias in MOVER_ALIASES:
                if isinstance(raw.get(alias[0]), dict):
                    raw[alias[0]].pop(alias[1], None)
        table = raw
        for part in path[:-1]:
            nxt = table.setdefault(part, {})
            if not isinstance(nxt, dict):
                raise InputError(".".join(path), value, f"{part} is not a table")
            table = nxt
        match = _INDEXED.match(path[-1])
        if match:
            _set_entry(table, path, match, value)
        else:
            table[path[-1]] = value
    return raw


def _set_entry(table: dict, path: list, match, value) -> None:
    """``table[key][i]...[j] = value`` for an override ``KEY[i]...[j]=VALUE`` (in range)."""
    key, indices = match["key"], [int(i) for i in re.findall(r"\d+", match["indices"])]
    dotted = ".".join(path[:-1] + [key])
    target = table.get(key)
    where = dotted
    for depth, index in enumerate(indices):
        if not isinstance(target, list):
            have = "holds no list" if target is None else f"is {target!r}, not a list"
            raise InputError(".".join(path), value, f"the scene's {where} {have}; set the whole list: "
                             f"{dotted}=[...]")
        if index >= len(target):
            size = f"has {len(target)} entries (index 0 to {len(target) - 1})" if target else "is empty"
            raise InputError(".".join(path), value, f"{where} {size}; set the whole list: {dotted}=[...]")
        if depth == len(indices) - 1:
            target[index] = value
        target, where = target[index], f"{where}[{index}]"


def read_scene_file(path: str | Path) -> dict:
    """Raw tables of a scene file, with clear errors for missing or malformed files."""
    path = Path(path)
    if path.is_dir():
        raise InputError("scene", str(path), "is a directory; give a scene file (TOML)")
    if path.exists() and not path.is_file():
        raise InputError("scene", str(path), "is not a regular file (a device, pipe or socket); give a "
                         "scene file (TOML)")
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
    """Markdown tables (docs/scenes.md): every scene key of every registered table with its
    default, allowed values and meaning; then the registered objectives."""
    rows = [("name", "(required)", "a string without slashes or control characters, not . or ..",
             "the scene's name (output folder)"),
            ("description", "", "a string", "one line about the scene")]
    for table in table_entries():
        rows += table.rows()

    def show(value):
        if isinstance(value, tuple):
            return "[" + ", ".join(show(v) for v in value) + "]"
        if isinstance(value, bool):
            return str(value).lower()
        return f'"{value}"' if isinstance(value, str) and value != "(required)" else str(value)
    lines = ["| key | default | allowed | meaning |", "|---|---|---|---|"]
    lines += [f"| `{k}` | {show(d)} | {a} | {doc} |".replace("|  |", "| |") for k, d, a, doc in rows]
    lines += ["", "| `design.objective` | quantity | unit | needs | definition |", "|---|---|---|---|---|"]
    lines += [f"| `{o.name}` | {o.label} | {o.units} | effects.{o.needs} | "
              f"{' '.join((o.__doc__ or '').split())} |" for o in OBJECTIVES]
    return "\n".join(lines) + "\n"
