"""No non-finite number is written as a result.

A NaN or an infinity in a result file would read as a number that was computed;
it is a solver that broke down. :func:`require_finite` looks through a result
(numbers, arrays, and dictionaries, lists or tuples of them) and raises a
:class:`~tofsi.errors.NumericalError` (exit status 3) naming each quantity that
is not finite and where it was met (e.g. the design iteration). ``None`` stands
for "does not apply here" (JSON null, a blank CSV cell) and passes.
"""

from __future__ import annotations

import math

import numpy as np

from tofsi.core.errors import NumericalError

SHOWN = 4           # quantities named in the message (all of them in the diagnostic)


def non_finite(value, name: str = "") -> list[str]:
    """The names (dotted keys, ``[i]`` for list entries) of the entries of ``value`` that are
    not finite; an array counts once, with how many of its entries are not finite."""
    if value is None or isinstance(value, (str, bool)):
        return []
    if isinstance(value, dict):
        return [bad for key, v in value.items() for bad in non_finite(v, f"{name}.{key}" if name else str(key))]
    if isinstance(value, (list, tuple)):
        return [bad for i, v in enumerate(value) for bad in non_finite(v, f"{name}[{i}]")]
    if isinstance(value, np.ndarray):
        if not np.issubdtype(value.dtype, np.number):
            return [bad for i, v in enumerate(value.ravel()) for bad in non_finite(v, f"{name}[{i}]")]
        count = int(np.size(value) - np.count_nonzero(np.isfinite(value)))
        return [f"{name} ({count} of {value.size} entries)"] if count else []
    if isinstance(value, (int, float, complex, np.number)):
        return [] if math.isfinite(abs(value)) else [f"{name} ({value})"]
    return []


def require_finite(value, where: str) -> None:
    """Raise a :class:`~tofsi.errors.NumericalError` if any entry of ``value`` is not finite:
    ``"<where>: not finite: objective (nan), ..."``; the diagnostic lists them all."""
    bad = non_finite(value)
    if bad:
        shown = ", ".join(bad[:SHOWN]) + (f" and {len(bad) - SHOWN} more" if len(bad) > SHOWN else "")
        raise NumericalError(f"{where}: not finite: {shown} (no element failed; a solver broke down or a "
                             "setting is out of floating-point range)", {"non_finite": bad})
