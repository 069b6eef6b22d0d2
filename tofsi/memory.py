"""Memory guard: estimate a run's peak memory from the mesh sizes, before anything is built.

A sparse LU on a structured 2D grid with a nested-dissection ordering has
``nnz(L + U) ~ c n log2 n`` entries for ``n`` unknowns (George 1973). The
peak of a solve is then modelled as

    peak = base + sum_fields (a_f E + b nnz_LU(field))

over the fields a command solves (each field's entry in
:data:`tofsi.registry.FIELDS` gives its unknowns, their kind of fill and its
``a_f``), with ``E`` elements (element matrices, assembly slots and the
fluid kernel's temporaries grow with ``E``) and 12 bytes per factor entry
(value and index) times ``b`` (the factorization's working space). The constants
are fitted to measured peaks of ``tofsi solve`` (``benchmarks/memory.py``;
the table in ``benchmarks/README.md`` gives the estimate against the
measured peak). Only the axes of the mesh are computed, so the guard
answers in milliseconds even for a mesh far too large to build.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from tofsi.errors import InputError
from tofsi.registry import FIELDS

GB = 1024.0 ** 3
BASE_BYTES = 0.15 * GB          # interpreter, NumPy/SciPy, the scene (measured 0.10 GB at import)
BYTES_PER_FACTOR_ENTRY = 21.0   # 12 stored + the factorization's working space, fitted to tofsi
                                # solve at 4005, 16200, 36315 elements (SuperLU), with the flow
                                # field's 8.6 kB per element
FILL = {"flow": 14.0, "flow-q1q1": 14.0, "q1-vector": 9.5}   # c in nnz(L + U) = c n log2 n, measured
                                                             # 12.6-13.9 (Taylor-Hood), 12.3-14.5 (Q1/Q1) / 9.1
BACKEND_FACTOR = {"superlu": 1.0, "pardiso": 1.1, "petsc": 1.2}   # measured 1.08 at 16200 elements


@dataclass(frozen=True)
class Estimate:
    """Estimated peak memory of a run [bytes] and its parts."""

    elements: int
    unknowns: dict
    factor_entries: dict
    peak_bytes: float

    @property
    def peak_gb(self) -> float:
        return self.peak_bytes / GB


def factor_entries(n: int, kind: str) -> float:
    """``nnz(L + U)`` of a nested-dissection LU with ``n`` unknowns on a 2D grid."""
    return FILL[kind] * n * math.log2(max(n, 2))


def estimate(scene, command: str = "solve", backend: str = "superlu") -> Estimate:
    """The peak memory of ``tofsi COMMAND`` on ``scene`` from its mesh sizes alone: every field
    the command solves (:meth:`tofsi.fields.Field.active`) adds its unknowns' LU and its
    per-element bytes."""
    from tofsi.channel import mesh_axes
    from tofsi.fields import GridSize
    xs, ys = mesh_axes(scene.geometry, scene.mesh)
    grid = GridSize(len(xs) - 1, len(ys) - 1)
    unknowns, entries, per_element = {}, {}, 0.0
    for field in FIELDS:
        if field.active(scene, command):
            need = field.memory(grid, scene)
            unknowns[field.title] = need.unknowns
            entries[field.title] = factor_entries(need.unknowns, need.fill)
            per_element += need.bytes_per_element
    scale = BACKEND_FACTOR.get(backend, 1.0)
    peak = BASE_BYTES + per_element * grid.elements + scale * BYTES_PER_FACTOR_ENTRY * sum(entries.values())
    return Estimate(grid.elements, unknowns, entries, peak)


def available_bytes() -> float:
    """Memory the machine can give now (``MemAvailable``; total memory where that is unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return math.inf


def check(scene, command: str, max_memory_gb: float | None = None) -> Estimate:
    """Refuse (InputError, exit 2) a run whose estimate exceeds the limit.

    The limit is ``max_memory_gb`` (``--max-memory``), else the scene's
    ``solver.max_memory_gb``, else the memory available now.
    """
    from tofsi.linalg.backends import resolve
    backend = scene.solver.linear_solver
    try:
        backend = resolve(backend)
    except InputError:
        pass                                     # reported where the backend is configured
    est = estimate(scene, command, backend)
    limit_gb = max_memory_gb or scene.solver.max_memory_gb or available_bytes() / GB
    if est.peak_gb > limit_gb:
        parts = ", ".join(f"{k} {v:,} unknowns" for k, v in est.unknowns.items())
        raise InputError("mesh.h_min", scene.mesh.h_min,
                         f"the {command} needs about {est.peak_gb:.1f} GB ({est.elements:,} elements; "
                         f"{parts}; sparse LU by {backend}) but {limit_gb:.1f} GB are allowed; "
                         "use a larger mesh.h_min/h_max, or raise --max-memory / solver.max_memory_gb")
    return est
