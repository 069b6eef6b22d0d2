"""Result files: VTU (ParaView), JSON, CSV -- written atomically.

Every file is written to a temporary name in its folder and renamed into
place, so an interrupted run never leaves a half-written file, and a run
that fails before producing anything leaves no folder behind (folders are
created on the first write). A file that cannot be written (disk full, a
file-size limit, a name too long) raises :class:`~tofsi.core.errors.WriteError`
naming it; the file it would have replaced stays as it was.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from pathlib import Path

import meshio
import numpy as np

from tofsi.core.errors import WriteError
from tofsi.core.finite import require_finite


_UMASK = os.umask(0)
os.umask(_UMASK)


def default_output(scene_name: str) -> Path:
    """``results/<scene name>/`` under the current directory."""
    return Path("results") / scene_name


def _plain(value):
    """``value`` as JSON's own types: numpy scalars and arrays as numbers and lists, paths as
    text, a non-finite float as None (JSON null)."""
    if isinstance(value, dict):
        return {k: _plain(x) for k, x in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(x) for x in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def to_json(obj) -> str:
    """JSON text of results (numpy scalars and arrays allowed; NaN written as null)."""
    return json.dumps(_plain(obj), indent=2, allow_nan=False)


def atomic_write(path: str | Path, write) -> Path:
    """Call ``write(tmp_path)`` then rename the temporary file to ``path``; an
    :class:`OSError` on the way becomes a :class:`WriteError` naming ``path``."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
        os.close(fd)
        write(tmp)
        os.chmod(tmp, 0o666 & ~_UMASK)          # mkstemp creates 0600; use the usual mode
        os.replace(tmp, path)
    except BaseException as err:
        if tmp is not None and os.path.exists(tmp):
            os.remove(tmp)
        if isinstance(err, OSError):
            raise WriteError.of(path, err) from err
        raise
    return path


def write_text(path, text: str) -> Path:
    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
    return atomic_write(path, write)


def write_json(path, obj) -> Path:
    return write_text(path, to_json(obj) + "\n")


def _finite_plain(value):
    """:func:`_plain` of a value the C encoder does not know (numpy scalars and arrays, paths),
    raising ValueError where it holds a non-finite number instead of writing null."""
    if isinstance(value, (np.floating, np.ndarray)) and not np.all(np.isfinite(value)):
        raise ValueError(f"a non-finite number in a record: {value!r}")
    return _plain(value)


def write_json_rows(path, rows: list[dict]) -> Path:
    """A JSON list of finite records, one record per line (a run's history: every row again at
    each iteration, so the compact C encoder, not :func:`to_json`'s indented one; a non-finite
    number, Python's or numpy's, raises ValueError)."""
    lines = (json.dumps(row, allow_nan=False, default=_finite_plain) for row in rows)
    return write_text(path, "[\n" + ",\n".join(lines) + "\n]\n" if rows else "[]\n")


def write_csv(path, rows: list[dict]) -> Path:
    """CSV with one column per key seen in any row (first-seen order; blanks where missing)."""
    buf = io.StringIO()
    if rows:
        fields = list(dict.fromkeys(k for row in rows for k in row))
        writer = csv.DictWriter(buf, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    return write_text(path, buf.getvalue())


def read_csv(path) -> list[dict]:
    """Rows written by :func:`write_csv`, with numbers, booleans and blanks (NaN) restored;
    any other text stays a string."""
    def value(text: str):
        if text in ("True", "False"):
            return text == "True"
        try:
            return float(text) if text else float("nan")
        except ValueError:
            return text
    with open(path, newline="") as f:
        return [{k: value(v) for k, v in row.items()} for row in csv.DictReader(f)]


def write_vtu(path, points: np.ndarray, cells: dict[str, np.ndarray],
              point_data: dict | None = None, cell_data: dict | None = None) -> Path:
    """Unstructured grid for ParaView. ``cells``: {"quad": (E, 4)} or {"quad9": (E, 9)}.

    2D vectors are padded with a zero z component so ParaView can warp by them. A point or
    an array entry that is not finite is a :class:`~tofsi.errors.NumericalError` naming the
    file and the array (:func:`tofsi.core.finite.require_finite`); nothing is written then.
    """
    require_finite({"points": points, **(point_data or {}), **(cell_data or {})}, Path(path).name)
    pts = np.column_stack([points, np.zeros(len(points))])

    def pad(v):
        v = np.asarray(v, dtype=float)
        return np.column_stack([v, np.zeros(len(v))]) if v.ndim == 2 and v.shape[1] == 2 else v

    mesh = meshio.Mesh(pts, [(k, np.asarray(v)) for k, v in cells.items()],
                       point_data={k: pad(v) for k, v in (point_data or {}).items()},
                       cell_data={k: [np.asarray(v, dtype=float)] for k, v in (cell_data or {}).items()})
    return atomic_write(path, lambda tmp: meshio.write(tmp, mesh, file_format="vtu"))
