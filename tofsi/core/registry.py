"""Registries: one home per concept.

An objective, a field of the coupled problem and a scene table are each one
*entry* of a registry, and the entry carries its whole story (an objective:
value, partials, label, units and the effect it needs; a field: its block,
its scene table, its unknowns for the memory guard, what it writes and the
figures it reports; a scene table: its record, how it is built, written and
resumed). Nothing else lists them: scene loading, provenance, ``--resume``,
the memory guard, the pictures and the generated scene reference all walk
the registry, so a new entry reaches every one of them and none can miss it.

The registries themselves live here, on the core floor, so that a lower
floor (the scene's records and loading) can name a registry's entries
without importing the modules that fill them. Each registry knows the
module of its built-in entries, its *home* (:mod:`tofsi.objectives`,
:mod:`tofsi.fields`, :mod:`tofsi.scene.tables`), by name only, and imports it
on first use, as entry points are loaded: whoever asks first sees every
entry, and nothing below the home imports it. Entries of your own are
registered with :meth:`Registry.register` (in a test, a script or a plugin).

    from tofsi.core.registry import OBJECTIVES
    OBJECTIVES.names()                       # ('compliance', 'dissipation', ...)
    OBJECTIVES.get("compliance").label       # 'compliance'
"""

from __future__ import annotations

import importlib
from typing import Generic, Iterator, TypeVar

from tofsi.core.errors import InputError

T = TypeVar("T")


class Registry(Generic[T]):
    """Entries of one concept by name, in the order they were registered.

    kind : what an entry is (``"objective"``), for messages;
    key : the scene key that names an entry (``"design.objective"``), for input errors;
    home : the module that registers the built-in entries, imported on first use.
    An entry is any object with a ``name`` attribute.
    """

    def __init__(self, kind: str, key: str, home: str):
        self.kind, self.key, self.home = kind, key, home
        self._entries: dict[str, T] = {}
        self._loaded = False

    def _load(self) -> dict[str, T]:
        """The entries, after the home module has registered the built-in ones."""
        if not self._loaded:
            self._loaded = True                   # the home's own registrations come through here
            try:
                importlib.import_module(self.home)
            except BaseException:
                self._loaded = False
                raise
        return self._entries

    def register(self, entry: T) -> T:
        """Add ``entry`` under ``entry.name`` (usable as a class decorator). A name is
        registered once: a second entry of the same name is an error, not a silent
        replacement."""
        name = getattr(entry, "name", None)
        if not isinstance(name, str) or not name:
            raise ValueError(f"a {self.kind} needs a non-empty string name, got {name!r}")
        entries = self._load()
        if name in entries and entries[name] is not entry:
            raise ValueError(f"a {self.kind} named {name!r} is registered already")
        entries[name] = entry
        return entry

    def unregister(self, name: str) -> None:
        """Remove an entry (a test's own entry, after the test)."""
        self._load().pop(name, None)

    def names(self) -> tuple[str, ...]:
        return tuple(self._load())

    def get(self, name: str) -> T:
        """The entry ``name``, or an :class:`InputError` naming the key and the allowed names."""
        entries = self._load()
        try:
            return entries[name]
        except KeyError:
            raise InputError(self.key, name, "allowed: one of "
                             + ", ".join(repr(n) for n in entries)) from None

    def __contains__(self, name) -> bool:
        return name in self._load()

    def __iter__(self) -> Iterator[T]:
        return iter(tuple(self._load().values()))

    def __len__(self) -> int:
        return len(self._load())


OBJECTIVES: Registry = Registry("objective", "design.objective", home="tofsi.objectives")
"""Quantities a design can minimize (:class:`tofsi.objectives.Objective` entries)."""

FIELDS: Registry = Registry("field", "effects", home="tofsi.fields")
"""Fields of the coupled problem (:class:`tofsi.fields.base.Field` entries), in dependency order."""

SCENE_TABLES: Registry = Registry("scene table", "scene", home="tofsi.scene.tables")
"""The tables of a scene file (:class:`tofsi.scene.tables.SceneTable` entries), in file order."""
