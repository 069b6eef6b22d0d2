"""Registries: one home per concept, each open to plugins through an entry-point group.

An objective, a field of the coupled problem, a mover, a structure material and a scene
table are each one *entry* of a registry, and the entry carries its whole story (an
objective: value, partials, label, units, its parameters and the field it needs; a field:
its block, its scene table, its unknowns for the memory guard, what it writes and the
figures it reports; a scene table: its record, how it is built, written and resumed).
Nothing else lists them: scene loading, provenance, ``--resume``, the memory guard, the
pictures and the generated scene reference all walk the registry, so a new entry reaches
every one of them and none can miss it.

The registries themselves live here, on the core floor, so that a lower floor (the
scene's records and loading) can name a registry's entries without importing the modules
that fill them. Each registry knows the module of its built-in entries, its *home*
(:mod:`tofsi.objectives`, :mod:`tofsi.fields`, :mod:`movers.registry`,
:mod:`tofsi.physics.materials`, :mod:`tofsi.scene.tables`), by name only, and imports it on
first use. Other packages add entries through the registry's entry-point group
(``tofsi.objectives``, ``tofsi.fields``, ``tofsi.movers``, ``tofsi.materials``;
``name = "package.module:attribute"``), loaded when the name is first asked for; a plugin
that fails to import is an :class:`~tofsi.core.errors.InputError` naming its entry point,
raised only when its name is asked for, and passed over (with one warning) where a registry
is walked, so scenes that do not use it keep working. Entries of your own are registered
with :meth:`Registry.register` (in a test, a script or a plugin).

    from tofsi.core.registry import OBJECTIVES
    OBJECTIVES.names()                       # ('compliance', 'dissipation', ...)
    OBJECTIVES.get("compliance").label       # 'compliance'
"""

from __future__ import annotations

import importlib
import logging
from importlib.metadata import entry_points
from typing import Generic, Iterator, TypeVar

from tofsi.core.errors import InputError

T = TypeVar("T")
log = logging.getLogger(__name__)


class Deferred:
    """An entry known by name and loaded on first use: ``module:attribute`` of the home's own
    lazy entries, or a plugin's entry point (``origin`` names it in messages)."""

    def __init__(self, name: str, target: str, origin: str):
        self.name, self.target, self.origin = name, target, origin

    def load(self):
        module, _, attribute = self.target.partition(":")
        entry = importlib.import_module(module)
        for part in filter(None, attribute.split(".")):
            entry = getattr(entry, part)
        return entry


class Registry(Generic[T]):
    """Entries of one concept by name, in the order they were registered (the home's, then
    the plugins' in name order, then later registrations).

    kind : what an entry is (``"objective"``), for messages;
    key : the scene key that names an entry (``"design.objective"``), for input errors;
    home : the module that registers the built-in entries, imported on first use;
    group : the entry-point group of plugins (None: no plugins).
    An entry is any object with a ``name`` attribute.
    """

    def __init__(self, kind: str, key: str, home: str, group: str | None = None):
        self.kind, self.key, self.home, self.group = kind, key, home, group
        self._entries: dict[str, T | Deferred] = {}
        self._builtin: set[str] = set()           # registered before the registry was first read
        self._warned: set[str] = set()
        self._home_imported = False
        self._read = False

    def _home(self) -> dict:
        """The entries, once the home module is imported (its own registrations come through
        here while it is; it may be imported first by someone else)."""
        if not self._home_imported:
            self._home_imported = True
            try:
                importlib.import_module(self.home)
            except BaseException:
                self._home_imported = False
                raise
        return self._entries

    def _load(self) -> dict:
        """The entries to read: the home's, then the entry-point group's plugins (known by name,
        loaded when asked for), then later registrations."""
        entries = self._home()
        if not self._read:
            self._read = True
            for point in sorted(entry_points(group=self.group) if self.group else (), key=lambda p: p.name):
                origin = f"entry point {point.name} = {point.value} (group {self.group})"
                entries.setdefault(point.name, Deferred(point.name, point.value, origin))
        return entries

    def _add(self, name: str, entry) -> None:
        entries = self._home()
        if name in entries and entries[name] is not entry:
            raise ValueError(f"a {self.kind} named {name!r} is registered already")
        entries[name] = entry
        if not self._read:
            self._builtin.add(name)

    def register(self, entry: T) -> T:
        """Add ``entry`` under ``entry.name`` (usable as a class decorator). A name is
        registered once: a second entry of the same name is an error, not a silent
        replacement."""
        name = getattr(entry, "name", None)
        if not isinstance(name, str) or not name:
            raise ValueError(f"a {self.kind} needs a non-empty string name, got {name!r}")
        self._add(name, entry)
        return entry

    def register_later(self, name: str, target: str) -> None:
        """Add the entry ``target`` (``"module:attribute"``) under ``name``, imported when first
        asked for (the home's entries that should not be imported before they are used)."""
        self._add(name, Deferred(name, target, f"{target} (registered as {name!r})"))

    def unregister(self, name: str) -> None:
        """Remove an entry (a test's own entry, after the test)."""
        self._load().pop(name, None)
        self._builtin.discard(name)

    def names(self) -> tuple[str, ...]:
        """Every name that can be asked for (plugins included, loaded or not)."""
        return tuple(self._load())

    def builtin(self) -> tuple[str, ...]:
        """The names registered before the registry was first read -- the home's (what the
        generated scene reference documents), not plugins' or those registered later."""
        return tuple(name for name in self._load() if name in self._builtin)

    def get(self, name: str) -> T:
        """The entry ``name`` (loaded now if it is a plugin's), or an :class:`InputError`
        naming the key and the allowed names -- or the plugin's entry point and why it failed."""
        entries = self._load()
        if name not in entries:
            raise InputError(self.key, name, "allowed: one of " + ", ".join(repr(n) for n in entries))
        entry = entries[name]
        if isinstance(entry, Deferred):
            try:
                loaded = entry.load()
            except Exception as err:              # a plugin's import error, whatever it is
                reason = (str(err).splitlines() or [""])[0]
                raise InputError(self.key, name, f"the {self.kind} plugin {entry.origin} failed to "
                                 f"load: {type(err).__name__}: {reason}") from err
            if getattr(loaded, "name", name) != name:
                raise InputError(self.key, name, f"the {self.kind} plugin {entry.origin} loads a "
                                 f"{self.kind} named {getattr(loaded, 'name', None)!r}")
            entries[name] = entry = loaded
        return entry

    def __contains__(self, name) -> bool:
        return name in self._load()

    def __iter__(self) -> Iterator[T]:
        """The entries that load; a plugin that fails is passed over with one warning (it fails
        with its reason where its name is asked for)."""
        for name in self.names():
            try:
                yield self.get(name)
            except InputError as err:
                if name not in self._warned:
                    self._warned.add(name)
                    log.warning("%s (passed over until a scene asks for it)", err.allowed)

    def __len__(self) -> int:
        return len(self._load())


OBJECTIVES: Registry = Registry("objective", "design.objective", home="tofsi.objectives",
                               group="tofsi.objectives")
"""Quantities a design can minimize (:class:`tofsi.objectives.Objective` entries)."""

FIELDS: Registry = Registry("field", "effects", home="tofsi.fields", group="tofsi.fields")
"""Fields of the coupled problem (:class:`tofsi.fields.base.Field` entries), in dependency order."""

SCENE_TABLES: Registry = Registry("scene table", "scene", home="tofsi.scene.tables")
"""The scene's own tables (:class:`tofsi.scene.tables.SceneTable` entries), in file order; the
fields' tables are the fields' (:attr:`tofsi.fields.base.Field.tables`)."""

MATERIALS: Registry = Registry("material", "structure.model", home="tofsi.physics.materials",
                              group="tofsi.materials")
"""The structure's materials (:class:`tofsi.physics.materials.Material` classes)."""

MOVERS: Registry = Registry("mover", "mover.name", home="movers.registry", group="tofsi.movers")
"""Mesh-motion backends (:class:`movers.base.Mover` classes), imported when first used."""
