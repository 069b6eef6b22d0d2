"""How much a run will write, estimated before computing, and whether the folder has room.

The files of a command and their sizes follow from the mesh's element
count (its axes only, as :mod:`tofsi.runs.memory` does: milliseconds), with
sizes per element measured on the shipped scenes at h = 0.1 to 0.025
(compressed VTU, uncompressed NumPy; ``tests/test_output_size.py`` checks
the estimate against the files runs write). A picture of fields is about
0.1 MB whatever the mesh (measured 0.07 to 0.18 MB), the mesh picture and
the convergence plot 0.03 and 0.045 MB.

A run is refused (:class:`~tofsi.core.errors.InputError`, exit 2) only when it
is *clearly* short of room: the free space of the output folder's file
system (plus what ``--overwrite`` will remove) below half the estimated
total, or a file-size limit (``ulimit -f``) below half the largest file.
What slips through (an estimate off by more, another program filling the
disk meanwhile) ends as a :class:`~tofsi.core.errors.WriteError` (exit 4) that
names the file and keeps what was written.
"""

from __future__ import annotations

import math
import os
import resource
import shutil
from dataclasses import dataclass
from pathlib import Path

from tofsi.core.errors import InputError
from tofsi.core.registry import FIELDS

MB = 1e6
CLEARLY_SHORT = 0.5              # refuse below this share of the estimate
PICTURE = 100e3                  # bytes of a PNG of fields (measured 70e3 .. 180e3)
MESH_PICTURE, PLOT = 30e3, 45e3  # mesh.png, convergence.png (measured 30e3 .. 35e3, 42e3 .. 47e3)
SMALL = 5e3                      # a JSON or CSV record
RESERVE = 32e3                   # kept free to record a failure (run.json; see run_folder)
BYTES_PER_ELEMENT = {            # measured: bytes / element at 200 .. 3200 elements
    "mesh": 15.0,                # mesh.vtu (region, layer, skewness, area; compresses well)
    "moved": 55.0,               # moved_mesh.vtu, tuned_mesh.vtu (+ displacement, area change)
    "solution": 250.0,           # solution.vtu (biquadratic cells, velocity and pressure)
    "design": 85.0,              # design_NNNN.vtu
    "state": 100.0,              # the state in checkpoint.npz
}


@dataclass(frozen=True)
class OutputEstimate:
    """Estimated size [bytes] of each file a run writes."""

    files: dict

    @property
    def total(self) -> float:
        return float(sum(self.files.values()))

    @property
    def largest(self) -> tuple[str, float]:
        return max(self.files.items(), key=lambda kv: kv[1]) if self.files else ("", 0.0)


def _elements(scene) -> tuple[int, int]:
    """``(elements, design elements)`` of the scene's mesh, from its axes."""
    import numpy as np
    from tofsi.mesh.channel import mesh_axes
    xs, ys = mesh_axes(scene.geometry, scene.mesh)
    n = (len(xs) - 1) * (len(ys) - 1)
    if not scene.geometry.design:
        return n, 0
    x0, x1, y0, y1 = scene.geometry.design
    cx, cy = 0.5 * (xs[1:] + xs[:-1]), 0.5 * (ys[1:] + ys[:-1])
    return n, int(np.sum((cx > x0) & (cx < x1)) * np.sum((cy > y0) & (cy < y1)))


def estimate(scene, command: str) -> OutputEstimate:
    """The files ``tofsi COMMAND`` writes for ``scene`` and their estimated sizes."""
    E, n_design = _elements(scene)
    per = {k: v * E for k, v in BYTES_PER_ELEMENT.items()}
    files = {"run.json": SMALL}
    if command == "mesh":
        files.update({"mesh.vtu": per["mesh"], "mesh.png": MESH_PICTURE})
    elif command in ("move", "tune"):
        name = "moved_mesh" if command == "move" else "tuned_mesh"
        files.update({f"{name}.vtu": per["moved"], f"{name}.png": PICTURE, f"{command}.json": SMALL})
    elif command == "solve":
        pictures = [n for field in FIELDS if field.active(scene, "solve") for n in field.picture_names]
        files.update({"solution.vtu": per["solution"], "solve.json": SMALL,
                      **{f"solution_{k}.png": PICTURE for k in pictures}})
    elif command == "optimize":
        o, d = scene.optimizer, scene.design
        shots = [f"{i:04d}" for i in range(0, o.max_iter, o.output_every)] + ["final"]
        for tag in shots:
            files.update({f"design_{tag}.vtu": per["design"], f"design_{tag}.png": PICTURE})
        held = min(o.max_iter, max(d.stage_iterations, 1))          # evaluations of one stage
        files.update({"checkpoint.npz": per["state"] + 4 * 8.0 * n_design * held,
                      "design.npy": 8.0 * n_design, "convergence.png": PLOT,
                      "history.csv": SMALL, "history.json": SMALL, "result.json": SMALL,
                      "design_series.pvd": SMALL})
    else:                                                            # check-gradients, study
        files.update({f"{command}.json": SMALL})
    return OutputEstimate(files)


def file_size_limit() -> float:
    """The largest file this process may write [bytes] (``ulimit -f``; inf without one)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    return math.inf if soft == resource.RLIM_INFINITY else float(soft)


def free_bytes(path) -> float:
    """Free space [bytes] on the file system of ``path`` (or of its nearest existing parent)."""
    existing = Path(os.path.abspath(path))
    while not existing.exists():
        existing = existing.parent
    return float(shutil.disk_usage(existing).free)


def check_room(folder, scene, command: str, freed: float = 0.0, key: str = "--output") -> OutputEstimate:
    """Refuse (``InputError``) a run clearly short of disk space or of the file-size limit;
    ``freed``: bytes the run removes first (a previous run's files under ``--overwrite``)."""
    est = estimate(scene, command)
    need = est.total + RESERVE
    free = free_bytes(folder) + freed
    if free < CLEARLY_SHORT * need:
        raise InputError(key, str(folder), f"the {command} writes about {need / MB:.2g} MB "
                         f"({len(est.files)} files), but only {free / MB:.2g} MB are free there; "
                         "free some space or choose another folder")
    name, size = est.largest
    limit = file_size_limit()
    if limit < CLEARLY_SHORT * size:
        raise InputError(key, str(folder), f"the {command} writes {name} of about {size / MB:.2g} MB, "
                         f"but files are limited to {limit / MB:.2g} MB (ulimit -f); raise the limit")
    return est
