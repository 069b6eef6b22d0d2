"""Saved designs (``design.npy`` of ``tofsi optimize``): read with plain, one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tofsi.core.errors import InputError


def read_design(path, n_design: int, key: str = "design.initial") -> np.ndarray:
    """The design variables ``(n_design,)`` stored at ``path``, each in [0, 1].

    Raises :class:`InputError` naming ``key`` for a missing file, a folder, a
    file that is not a NumPy ``.npy`` array (text, pickles), the wrong number
    of values, or values that are not finite or lie outside [0, 1] (a design
    is never clipped silently).
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(key, str(path), "is a directory; give a design.npy file of an earlier run")
    if not p.is_file():
        raise InputError(key, str(path), "no such file (a design.npy of an earlier run)")
    try:
        gamma = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError):
        raise InputError(key, str(path), "is not a NumPy .npy file (tofsi optimize writes design.npy; "
                                         "text or pickled files are not read)") from None
    kinds = {"U": "text", "S": "bytes", "c": "complex numbers", "O": "objects", "M": "dates",
             "m": "time spans", "V": "records"}
    if isinstance(gamma, np.ndarray) and gamma.dtype.kind not in "biuf":
        what = kinds.get(gamma.dtype.kind, f"values of type {gamma.dtype}")
        raise InputError(key, str(path), f"holds {what} (dtype {gamma.dtype}); needs {n_design} real "
                                         "numbers in [0, 1] (this scene's design variables)")
    if not isinstance(gamma, np.ndarray) or gamma.shape != (n_design,):
        shape = getattr(gamma, "shape", None)
        raise InputError(key, str(path), f"needs {n_design} numbers (this scene's design variables), "
                                         f"got an array of shape {shape}")
    gamma = gamma.astype(float)
    if not np.all(np.isfinite(gamma)):
        raise InputError(key, str(path), "holds NaN or inf values; allowed: numbers in [0, 1]")
    if gamma.min() < 0.0 or gamma.max() > 1.0:
        raise InputError(key, str(path), f"values lie in [{gamma.min():.4g}, {gamma.max():.4g}]; "
                                         "allowed: [0, 1] (design variables are not clipped)")
    return gamma
