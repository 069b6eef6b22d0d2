"""Frozen configuration records built from TOML tables, validated on the way in.

A record is a frozen dataclass whose fields are declared with :func:`option`,
which states the default, the allowed range and a one-line meaning::

    @dataclass(frozen=True)
    class Channel:
        length: float = option(2.0, gt=0, doc="channel length [m]")

:func:`build` turns a raw TOML table into such a record: unknown keys,
wrong types, NaN/inf and out-of-range values are rejected with an
:class:`~tofsi.core.errors.InputError` that names the dotted key, the value and
what is allowed. Cross-field checks live in the record's ``__post_init__``
and raise ``InputError`` with the key relative to the record; :func:`build`
qualifies it with the record's path.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any

from tofsi.core.errors import InputError


def option(default: Any = dataclasses.MISSING, *, gt=None, ge=None, lt=None, le=None,
           choices=None, length=None, doc: str = ""):
    """A dataclass field with its allowed range (applied to every element of a list).

    choices : the allowed values, or a function returning them (a registry read when
    a table is validated, e.g. the objectives)
    """
    meta = dict(gt=gt, ge=ge, lt=lt, le=le, choices=choices, length=length, doc=doc)
    if dataclasses.is_dataclass(default):
        return dataclasses.field(default_factory=lambda: default, metadata=meta)
    if isinstance(default, (list, dict)):
        raise TypeError("use a tuple default for list options")
    return dataclasses.field(default=default, metadata=meta)


def choices_of(meta: dict) -> tuple:
    """The allowed values of an option (calling a registry function if given one)."""
    choices = meta.get("choices")
    return tuple(choices()) if callable(choices) else tuple(choices or ())


def join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def describe_range(meta: dict) -> str:
    """Human-readable statement of the allowed values, e.g. ``0 < value <= 1``."""
    if meta.get("choices"):
        return "allowed: one of " + ", ".join(repr(c) for c in choices_of(meta))
    lower = f"{meta['gt']} < " if meta.get("gt") is not None else (
        f"{meta['ge']} <= " if meta.get("ge") is not None else "")
    upper = f" < {meta['lt']}" if meta.get("lt") is not None else (
        f" <= {meta['le']}" if meta.get("le") is not None else "")
    if not lower and not upper:
        return "allowed: any finite value"
    return f"allowed: {lower}value{upper}"


def check_range(value: float, key: str, meta: dict) -> None:
    ok = ((meta.get("gt") is None or value > meta["gt"])
          and (meta.get("ge") is None or value >= meta["ge"])
          and (meta.get("lt") is None or value < meta["lt"])
          and (meta.get("le") is None or value <= meta["le"]))
    if not ok:
        raise InputError(key, value, describe_range(meta))


def coerce(tp: Any, value: Any, key: str, meta: dict) -> Any:
    """Convert a raw TOML value to the annotated type, checking its range."""
    if dataclasses.is_dataclass(tp):
        return build(tp, value, key)
    origin = typing.get_origin(tp)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise InputError(key, value, "expected a list")
        inner = meta
        if args[0] in (float, int, str, bool):      # the innermost list: its length is checked
            if meta.get("length") is not None and len(value) != meta["length"]:
                raise InputError(key, value, f"expected a list of {meta['length']} values")
            inner = dict(meta, length=None)
        return tuple(coerce(args[0], v, join(key, i), inner) for i, v in enumerate(value))
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return coerce(options[0], value, key, meta)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(key, value, "expected a number")
        value = float(value)
        if not math.isfinite(value):
            raise InputError(key, value, "must be finite; " + describe_range(meta))
        check_range(value, key, meta)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(key, value, "expected a whole number; " + describe_range(meta))
        check_range(value, key, meta)
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise InputError(key, value, "expected true or false")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise InputError(key, value, "expected a string")
        if meta.get("choices") and value not in choices_of(meta):
            raise InputError(key, value, describe_range(meta))
        return value
    raise TypeError(f"unsupported option type {tp!r} at {key}")


def build(cls: type, raw: Any, path: str = ""):
    """Validate a raw table and build the frozen record ``cls`` from it."""
    if not isinstance(raw, dict):
        raise InputError(path, raw, "expected a table")
    hints = typing.get_type_hints(cls)
    known = [f for f in dataclasses.fields(cls) if f.init]
    names = {f.name for f in known}
    for key in raw:
        if key not in names:
            raise InputError(join(path, key), raw[key],
                             "unknown key; allowed keys: " + ", ".join(sorted(names)))
    kwargs = {}
    for f in known:
        if f.name in raw:
            kwargs[f.name] = coerce(hints[f.name], raw[f.name], join(path, f.name), f.metadata)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise InputError(join(path, f.name), None, "required key is missing")
    try:
        return cls(**kwargs)
    except InputError as err:
        raise err.under(path) from None


def _allowed(tp, meta: dict) -> str:
    """What a field accepts, in words."""
    if meta.get("choices"):
        text = describe_range(meta)[len("allowed: "):]
        return f"list of: {text}" if typing.get_origin(tp) is tuple else text
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if typing.get_origin(tp) is tuple:
        inner = typing.get_args(tp)[0]
        if typing.get_origin(inner) is tuple:
            return f"list of [{meta.get('length') or '...'} numbers]"
        ranged = describe_range(meta)
        return "list of numbers" + ("" if "any finite" in ranged else f", each {ranged[len('allowed: '):]}")
    return describe_range(meta)[len("allowed: "):]


def documentation(cls: type, path: str = "") -> list[tuple[str, Any, str, str]]:
    """Rows ``(key, default, allowed, meaning)`` of a record (the scene reference)."""
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        key = join(path, f.name)
        if dataclasses.is_dataclass(hints[f.name]):
            rows += documentation(hints[f.name], key)
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        rows.append((key, default, _allowed(hints[f.name], f.metadata), f.metadata.get("doc", "")))
    return rows
