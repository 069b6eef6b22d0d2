"""Name -> mover class: the built-in movers of :data:`tofsi.core.registry.MOVERS`, imported when
first used; plugins come through the entry-point group ``tofsi.movers``."""

from __future__ import annotations

from tofsi.core.config import build
from tofsi.core.registry import MOVERS

_BUILTIN = {
    "linear": "movers.linear:LinearElasticMover",
    "spring": "movers.spring:SpringMover",
    "yeoh": "movers.yeoh:YeohMover",
}
for _name, _target in _BUILTIN.items():
    MOVERS.register_later(_name, _target)


def register(name: str, target) -> None:
    """Register a mover class (or a ``"module:Class"`` string, imported when first used) under
    ``name``."""
    if not name or name == "none":
        raise ValueError(f"invalid mover name {name!r}")
    if isinstance(target, str):
        MOVERS.register_later(name, target)
    elif getattr(target, "name", name) != name:
        raise ValueError(f"the mover class {target.__name__} is named {target.name!r}, not {name!r}")
    else:
        MOVERS.register(target)


def available() -> list[str]:
    """Names of every mover that can be asked for (plugins included, loaded or not)."""
    return sorted(MOVERS.names())


def mover_class(name: str):
    """The class registered under ``name`` (an input error naming ``mover.name``, or a plugin's
    entry point that fails to load)."""
    return MOVERS.get(name)


def create(name: str, **params):
    """A mover instance, its parameters validated like the scene table ``[mover.<name>]``."""
    cls = mover_class(name)
    return cls(build(cls.Params, params, f"mover.{name}"))
