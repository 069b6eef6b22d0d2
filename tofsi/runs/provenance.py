"""What defines a run: the effective scene as plain tables and TOML, the versions, run.json.

Every output folder gets a ``run.json`` (see :mod:`tofsi.runs.run_folder`) holding

* ``scene``: the effective scene (after ``--set``) as TOML text, every key
  written out, so ``tomllib.loads(run["scene"])`` is a scene file that
  reproduces the run;
* ``overrides``, ``command_line``, ``cwd``, ``scene_file``;
* ``tofsi_version``, ``git_commit`` (with ``git_dirty``) when tofsi runs
  from a git checkout, the Python, NumPy and SciPy versions;
* ``started``, ``finished`` (ISO 8601, UTC), ``exit_status``, ``status`` and,
  for optimizations, ``stop_reason`` (max_iter, converged, interrupted, ...);
* ``files``: the files the run wrote.

:func:`scene_tables` is also the record a checkpoint keeps, so that
``--resume`` can name every key that differs (:mod:`tofsi.optimization.resume`).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
from functools import lru_cache
from pathlib import Path

from tofsi.core.version import VERSION
from tofsi.scene.scene import table_entries
from tofsi.scene.tables import plain


def scene_tables(scene) -> dict:
    """The effective scene as raw tables, every registered table written out:
    ``scene_from_dict(scene_tables(s)) == s``."""
    tables = {"name": scene.name, "description": scene.description}
    for table in table_entries():
        tables[table.name] = table.write(getattr(scene, table.name))
    return tables


def resumable_keys() -> tuple[str, ...]:
    """Dotted keys a ``--resume`` may change (they cannot change the replayed history)."""
    return ("description", *(f"{t.name}.{k}" for t in table_entries() for k in t.resumable))


def flatten(tables: dict, prefix: str = "") -> dict:
    """``{"mesh": {"h_min": 0.1}}`` -> ``{"mesh.h_min": 0.1}`` (lists stay values)."""
    flat = {}
    for key, value in tables.items():
        dotted = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            flat.update(flatten(value, dotted))
        else:
            flat[dotted] = value
    return flat


def differing_keys(old: dict, new: dict) -> list[str]:
    """Dotted keys whose values differ between two sets of tables (or exist in one only)."""
    a, b = flatten(old), flatten(new)
    return sorted(k for k in set(a) | set(b) if a.get(k, None) != b.get(k, None) or (k in a) != (k in b))


# ---- TOML -------------------------------------------------------------------------------
def _toml_key(key: str) -> str:
    bare = key and all(c.isascii() and (c.isalnum() or c in "-_") for c in key)
    return key if bare else _toml_value(key)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)                      # finite: the scene rejects NaN and inf
    if isinstance(value, str):                  # JSON escapes are TOML basic-string escapes
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


def to_toml(tables: dict) -> str:
    """TOML text of nested tables (scalars and lists of scalars or lists)."""
    lines: list[str] = []

    def emit(prefix: str, table: dict) -> None:
        scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
        subtables = {k: v for k, v in table.items() if isinstance(v, dict)}
        if prefix and (scalars or not subtables):
            lines.append(f"\n[{prefix}]")
        lines.extend(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in scalars.items())
        for k, v in subtables.items():
            emit(f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k), v)
    emit("", tables)
    return "\n".join(lines).lstrip("\n") + "\n"


def scene_toml(scene) -> str:
    """The effective scene as a TOML scene file."""
    return to_toml(scene_tables(scene))


# ---- versions and the run record -----------------------------------------------------------
def now() -> str:
    """The current time, ISO 8601 in UTC to the second."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


@lru_cache(maxsize=1)
def git_commit() -> tuple[str | None, bool | None]:
    """``(commit, dirty)`` of the checkout tofsi runs from, or ``(None, None)`` when tofsi
    is not a git checkout (an installed wheel) or git is unavailable."""
    root = Path(__file__).resolve().parents[2]
    if not ((root / ".git").exists() and (root / "pyproject.toml").is_file()):
        return None, None

    def git(*args):
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
    try:
        commit = git("rev-parse", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return None, None
    return commit, dirty


def versions() -> dict:
    import numpy
    import scipy

    commit, dirty = git_commit()
    return {"tofsi_version": VERSION, "git_commit": commit, "git_dirty": dirty,
            "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__}


def run_record(scene, overrides, command_line, program: str) -> dict:
    """The provenance of a run that is about to start (``run.json`` before its end)."""
    return {"program": program, "command_line": list(command_line), "cwd": os.getcwd(),
            "scene_file": scene.source, "scene_name": scene.name, "overrides": list(overrides or []),
            **versions(), "started": now(), "finished": None, "status": "running",
            "exit_status": None, "scene": scene_toml(scene)}


def mover_settings(scene) -> dict:
    """The settings that define a move: the motion, the mover with its parameters, the mesh."""
    options = scene.mover.options
    return {"deformation": plain(scene.deformation),
            "mover": {"name": scene.mover.name, "layers": list(scene.mover.layers),
                      "band": plain(scene.mover.band), "params": plain(options) if options is not None else {}},
            "mesh": plain(scene.mesh)}


def solve_settings(model) -> dict:
    """The settings that define a model's forward solve: the effects, the mesh, the coupling
    and every active field's own tables."""
    tables = scene_tables(model.scene)
    keys = ["effects", "mesh", "coupled", *(t.name for field in model.fields for t in field.tables)]
    return {k: tables[k] for k in dict.fromkeys(keys)}
