"""Parametric studies: run a scene over a grid of key values, collect the figures.

A sweep names a dotted scene key and its values:

* ``mover.yeoh.A20=1e-1:1e5:*10``  -- geometric: start, stop, factor;
* ``mover.layers[0]=1:6:0.25``    -- linear: start, stop (inclusive), step;
* ``mover.name=spring,linear,yeoh``  -- a list of values (TOML values or bare words).

Several sweeps form their Cartesian product. ``KEY[i]`` sweeps one entry of
a list key; the entries of one list are combined into one override
(``mover.layers=[f1, f2]``). Each point runs in a worker process (``jobs``),
and a run that fails numerically is recorded with ``status = "failed"``,
``converged = False`` and the figures of its diagnostic, not dropped.
"""

from __future__ import annotations

import itertools
import multiprocessing
import re
import signal
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from tofsi.core.errors import InputError, NumericalError
from tofsi.scene.scene import parse_override

_INDEXED = re.compile(r"^(?P<key>[\w.]+)\[(?P<index>\d+)\]$")
MAX_POINTS = 100_000          # sweep points (one run each): counted before any value is made


@dataclass(frozen=True)
class Sweep:
    key: str
    values: tuple


def _number(text: str, sweep: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError("--sweep", sweep, f"{text!r} is not a number") from None
    if not np.isfinite(value):
        raise InputError("--sweep", sweep, f"{text!r} is not a finite number")
    return value


def _count(span: float, step: float, sweep: str) -> int:
    """Values of a range whose ``span`` holds ``span / step`` steps, refused beyond MAX_POINTS
    (counted before any array is made)."""
    steps = span / step + 1e-9
    if not np.isfinite(steps) or steps + 1 > MAX_POINTS:
        raise InputError("--sweep", sweep, f"gives {steps + 1:.3g} values; allowed: at most {MAX_POINTS} "
                         "(use a larger step or factor)")
    return int(np.floor(steps)) + 1


def parse_sweep(text: str) -> Sweep:
    """``KEY=START:STOP:STEP``, ``KEY=START:STOP:*FACTOR`` or ``KEY=v1,v2,...``."""
    key, sep, spec = text.partition("=")
    key, spec = key.strip(), spec.strip()
    if not sep or not key or not spec:
        raise InputError("--sweep", text, "expected KEY=START:STOP:STEP, KEY=START:STOP:*FACTOR "
                                          "or KEY=V1,V2,...")
    if ":" in spec:
        parts = spec.split(":")
        if len(parts) != 3:
            raise InputError("--sweep", text, "a range needs START:STOP:STEP")
        start, stop = _number(parts[0], text), _number(parts[1], text)
        if parts[2].startswith("*"):
            factor = _number(parts[2][1:], text)
            if start <= 0 or stop < start or factor <= 1:
                raise InputError("--sweep", text, "a geometric range needs 0 < START <= STOP, FACTOR > 1")
            count = _count(np.log(stop / start), np.log(factor), text)
            values = start * factor ** np.arange(count)
        else:
            step = _number(parts[2], text)
            if step <= 0 or stop < start:
                raise InputError("--sweep", text, "a range needs START <= STOP and STEP > 0")
            count = _count(stop - start, step, text)
            values = start + step * np.arange(count)
        return Sweep(key, tuple(float(v) for v in np.round(values, 12)))
    values = tuple(parse_override(f"v={v.strip()}")[1] for v in spec.split(","))
    return Sweep(key, values)


def points(sweeps: list[Sweep]) -> list[dict]:
    """The Cartesian product of the sweeps, one ``{key: value}`` per run (at most MAX_POINTS)."""
    total = int(np.prod([len(s.values) for s in sweeps], dtype=float))
    if total > MAX_POINTS:
        raise InputError("--sweep", " ".join(f"{s.key} ({len(s.values)})" for s in sweeps),
                         f"the grid has {total:,} points; allowed: at most {MAX_POINTS:,} runs")
    keys = [s.key for s in sweeps]
    return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*(s.values for s in sweeps))]


def overrides_for(point: dict) -> list[str]:
    """Override strings for a sweep point; ``KEY[i]`` entries join into one list."""
    lists: dict[str, dict[int, object]] = {}
    out = []
    for key, value in point.items():
        match = _INDEXED.match(key)
        if match:
            lists.setdefault(match["key"], {})[int(match["index"])] = value
        else:
            out.append(f"{key}={_toml(value)}")
    for key, entries in lists.items():
        size = max(entries) + 1
        if set(entries) != set(range(size)):
            raise InputError("--sweep", key, f"sweeps of {key}[i] must cover every index 0..{size - 1}")
        out.append(f"{key}=[{', '.join(_toml(entries[i]) for i in range(size))}]")
    return out


def _toml(value) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value)


def _run_point(args):
    runner, scene_path, overrides, point = args
    from tofsi.scene.scene import load_scene
    t0 = time.perf_counter()
    try:
        figures = {"status": "ok", **runner(load_scene(scene_path, overrides))}
    except NumericalError as err:
        figures = {"status": "failed", "converged": False, "error": str(err).splitlines()[0],
                   **{k: v for k, v in err.diagnostic.get("quality", {}).items()
                      if k in ("min_skewness", "min_area_change", "max_area_change", "n_inverted")}}
    return {**point, **figures, "run_time_s": time.perf_counter() - t0}


def _worker_init() -> None:
    """Workers leave Ctrl-C to the parent (which stops them) and die on SIGTERM."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def plan(scene_path, base_overrides: list[str], sweeps: list[Sweep], runner) -> list[tuple]:
    """The tasks of a study, one per sweep point; the first and last point's scenes are
    loaded here, so bad keys and values fail before any work."""
    grid = points(sweeps)
    tasks = [(runner, str(scene_path), list(base_overrides) + overrides_for(p), p) for p in grid]
    from tofsi.scene.scene import load_scene
    for task in tasks[:1] + tasks[-1:]:
        load_scene(task[1], task[2])
    return tasks


def run_tasks(tasks: list[tuple], jobs: int = 1, on_row: Callable[[dict], None] | None = None) -> list[dict]:
    """Run planned tasks in order (``jobs`` worker processes); ``on_row`` sees each finished row
    at once, so an interrupted study keeps its finished points. Rows carry ``status``: ``ok``
    or ``failed`` (a numerical failure, recorded with the failed state's figures)."""
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InputError("--jobs", jobs, "allowed: a whole number >= 1 (worker processes)")
    rows: list[dict] = []

    def keep(row):
        rows.append(row)
        if on_row:
            on_row(row)
    if jobs == 1 or len(tasks) <= 1:
        for task in tasks:
            keep(_run_point(task))
        return rows
    with multiprocessing.Pool(min(jobs, len(tasks)), initializer=_worker_init) as pool:
        for row in pool.imap(_run_point, tasks):           # leaving the block terminates workers
            keep(row)
    return rows


def run_study(scene_path, base_overrides: list[str], sweeps: list[Sweep],
              runner: Callable[[object], dict], jobs: int = 1, progress=None) -> list[dict]:
    """Run ``runner(scene)`` at every sweep point; rows in sweep order.

    ``runner`` must be a module-level function (it is sent to worker processes).
    """
    tasks = plan(scene_path, base_overrides, sweeps, runner)
    count = [0]

    def on_row(row):
        count[0] += 1
        if progress:
            progress(count[0], len(tasks), row)
    return run_tasks(tasks, jobs, on_row)


def best(rows: list[dict], figure: str = "min_skewness") -> dict | None:
    """The row with the largest ``figure`` (NaN and missing values ignored)."""
    valid = [r for r in rows if isinstance(r.get(figure), (int, float)) and np.isfinite(r[figure])]
    return max(valid, key=lambda r: r[figure]) if valid else None
