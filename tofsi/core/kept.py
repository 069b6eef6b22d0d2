"""Kept evaluations: the last value of a computation, keyed by every input it reads.

A Newton's line-search trial, the next iterate's linearization and the
fluid load at one state all ask the flow's element kernel for the same
point; keeping the last evaluation lets them share one pass. Such a value
is safe only when its key holds *every* input -- arrays by content, settings
records, the continuation record, and attributes of the owner that someone
could change -- and when nobody can change the value itself. Hence one key
builder, :func:`input_key`, and one holder, :class:`Kept`, whose arrays are
made read-only (``writeable = False``).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np


def input_key(*inputs) -> tuple:
    """A comparable key of ``inputs``: arrays by dtype, shape and content; everything else
    (None, numbers, strings, frozen settings records, functions) as it is."""
    def one(value):
        if isinstance(value, np.ndarray):
            return ("array", value.dtype.str, value.shape, value.tobytes())
        return value
    return tuple(one(v) for v in inputs)


def freeze(value):
    """``value`` with every array in it (nested in tuples, lists and dicts) made read-only."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, (tuple, list)):
        for v in value:
            freeze(v)
    elif isinstance(value, dict):
        for v in value.values():
            freeze(v)
    return value


class Kept:
    """The last evaluation of one computation: ``get(key, build)`` returns the kept value when
    ``key`` (from :func:`input_key`) equals the last one, else ``build()``, frozen and kept.
    The old value is let go before the new one is built, so the two are never held together
    (a design point's state with its factorizations, an element Jacobian array).
    ``builds`` counts the evaluations made (tests see a fresh value being built)."""

    def __init__(self):
        self._key: tuple | None = None
        self._value: Any = None
        self.builds = 0

    def get(self, key: tuple, build: Callable[[], Any]):
        if self._key is None or self._key != key:
            self._key, self._value = None, None
            value = freeze(build())
            self._key, self._value = key, value
            self.builds += 1
        return self._value

    def peek(self, key: tuple):
        """The kept value if its key is ``key``, else None (nothing is built)."""
        return self._value if self._key is not None and self._key == key else None
