"""Name -> mover class registry, with entry-point discovery."""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from tofsi.core.config import build
from tofsi.core.errors import InputError

_BUILTIN = {
    "linear": "movers.linear:LinearElasticMover",
    "spring": "movers.spring:SpringMover",
    "yeoh": "movers.yeoh:YeohMover",
}
_registered: dict[str, object] = {}


def register(name: str, target) -> None:
    """Register a mover class (or a ``"module:Class"`` string) under ``name``."""
    if not name or name == "none":
        raise ValueError(f"invalid mover name {name!r}")
    _registered[name] = target


def _entries() -> dict[str, object]:
    found = dict(_BUILTIN)
    for ep in entry_points(group="tofsi.movers"):
        found.setdefault(ep.name, ep.value)
    found.update(_registered)
    return found


def available() -> list[str]:
    """Names of every mover that can be created."""
    return sorted(_entries())


def mover_class(name: str):
    """The class registered under ``name``."""
    entries = _entries()
    if name not in entries:
        raise InputError("mover.name", name, "allowed: one of " + ", ".join(repr(n) for n in sorted(entries)))
    target = entries[name]
    if isinstance(target, str):
        module, _, attr = target.partition(":")
        target = getattr(importlib.import_module(module), attr)
    return target


def create(name: str, **params):
    """A mover instance, its parameters validated like the scene table ``[mover.<name>]``."""
    cls = mover_class(name)
    return cls(build(cls.Params, params, f"mover.{name}"))
