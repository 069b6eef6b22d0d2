"""Memory guard: estimate a run's peak memory from the mesh sizes, before anything is built.

A sparse LU on a structured 2D grid with a nested-dissection ordering has
``nnz(L + U) ~ c n log2 n`` entries for ``n`` unknowns (George 1973). The
peak of ``tofsi solve`` is modelled as

    direct:     peak = base + sum_fields a_f E + b nnz_LU(field)
    iterative:  peak = base + sum_fields a_f E + c_kind n_f      (no factors; AMG and Krylov, O(n))

over the fields the command solves (each field's entry in
:data:`tofsi.core.registry.FIELDS` gives its unknowns ``n_f``, their kind of fill
and its ``a_f``), ``E`` elements, ``b`` bytes per factor entry (12 stored +
the factorization's working space) and ``c_kind`` bytes per unknown of the
iterative solvers (hierarchies, Krylov bases, the blocks they copy). Every
other command is a multiple of that (:data:`COMMAND_FACTOR`: ``optimize``
and ``check-gradients`` keep the adjoint's blocks beside a solve) plus, for
those two, the design filter's ``O(E)`` (a stencil, no matrix:
:data:`FILTER_BYTES_PER_ELEMENT`), except ``tofsi mesh`` (the mesh
alone, :data:`MESH_BYTES_PER_ELEMENT`). Under ``mpiexec -n P`` with the
``petsc`` backend the factors are split across the ranks and everything else
is replicated: per rank ``base + f (sum a_f E + b nnz_LU / P)``, and the
guard compares the P ranks' total with the machine. The constants are
fitted to measured peaks (``ru_maxrss`` of fresh processes, SuperLU and the
iterative path; the table in ``benchmarks/README.md`` gives estimate against
measured for every command). Only the axes of the mesh are computed, so the
guard answers in milliseconds even for a mesh far too large to build.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from tofsi.core.errors import InputError
from tofsi.core.registry import FIELDS

GB = 1024.0 ** 3
BASE_BYTES = 0.13 * GB          # interpreter, NumPy/SciPy, the scene (measured 0.10 GB at import, 0.14 GB for
                                # a whole solve at 800 elements; 0.15 before issue 34 made the solves leaner)
BYTES_PER_FACTOR_ENTRY = 22.2   # 12 stored + the factorization's working space; fitted to tofsi solve
                                # at 16 200-129 795 elements (SuperLU); the fields' a_f refitted after
                                # the fluid kernel ran in chunks (16 200 and 64 980 elements)
FILL = {"flow": 14.0, "flow-q1q1": 14.0, "q1-vector": 9.5}   # c in nnz(L + U) = c n log2 n, measured
                                                             # 12.6-13.9 (Taylor-Hood), 12.3-14.5 (Q1/Q1) / 9.1
BACKEND_FACTOR = {"superlu": 1.0, "pardiso": 1.1, "petsc": 1.2}   # measured 1.08 at 16200 elements
ITERATIVE_BYTES_PER_UNKNOWN = {"flow": 1.35e3, "q1-vector": 1.9e3}  # fitted to tofsi solve / move on
                                # the iterative path (flow: 16 200 and 64 980 elements after issue 34's
                                # GMRES(30), int32 slots, no kept element matrices, the Jacobian as its
                                # blocks shared with the preconditioner, the AMG setup without copies;
                                # 2.35e3 before the last two, 3.8e3 before issue 34; 5e3-1.6e5 mesh)
COMMAND_FACTOR = {"solve": 1.0, "optimize": 1.10, "check-gradients": 1.70, "move": 1.0, "tune": 1.0,
                  "study": 1.0}  # peak over the solve model (above base): optimize measured 1.06-1.08
                                 # at 16 200 elements once a design point's state is let go before
                                 # the next is solved (1.68-1.71 at 16k-130k when both were held)
FILTER_BYTES_PER_ELEMENT = 64.0  # the design filter, a stencil (tofsi.optimization.design): Hs, b and the kernel's FFT
                                 # held (23 B measured at 1e6 elements) and its applications' E-vectors;
                                 # optimize and check-gradients (the matrix it replaced: (r/h)^2 entries)
MESH_BASE_BYTES = 0.10 * GB     # tofsi mesh: the interpreter and the mesh alone
MESH_BYTES_PER_ELEMENT = 0.65e3   # fitted to tofsi mesh at 5e3-1.6e5 elements


@dataclass(frozen=True)
class Estimate:
    """Estimated peak memory of a run [bytes] and its parts (``peak_bytes`` per rank)."""

    elements: int
    unknowns: dict
    factor_entries: dict
    peak_bytes: float
    path: str = "direct"
    ranks: int = 1

    @property
    def peak_gb(self) -> float:
        return self.peak_bytes / GB

    @property
    def total_gb(self) -> float:
        """All ranks together (they share the machine under ``mpiexec``)."""
        return self.peak_gb * self.ranks


def factor_entries(n: int, kind: str) -> float:
    """``nnz(L + U)`` of a nested-dissection LU with ``n`` unknowns on a 2D grid."""
    return FILL[kind] * n * math.log2(max(n, 2))


def mpi_ranks() -> int:
    """Processes started by ``mpiexec`` (1 without an MPI launcher), from the launcher's environment."""
    for name in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MV2_COMM_WORLD_SIZE"):
        if os.environ.get(name, "").isdigit():
            return max(int(os.environ[name]), 1)
    return 1


def estimate(scene, command: str = "solve", backend: str = "superlu", ranks: int = 1) -> Estimate:
    """The peak memory of ``tofsi COMMAND`` on ``scene`` from its mesh sizes alone: every field
    the command solves (:meth:`tofsi.fields.base.Field.active`) adds its per-element bytes and its
    unknowns' LU (``backend`` a direct one) or iterative solvers (``backend = "iterative"``);
    ``ranks``: processes under ``mpiexec`` (the petsc backend splits the factors)."""
    from tofsi.mesh.channel import mesh_axes
    from tofsi.fields.base import GridSize
    xs, ys = mesh_axes(scene.geometry, scene.mesh)
    grid = GridSize(len(xs) - 1, len(ys) - 1)
    if command == "mesh":
        return Estimate(grid.elements, {}, {}, MESH_BASE_BYTES + MESH_BYTES_PER_ELEMENT * grid.elements)
    iterative = backend == "iterative"
    split = ranks if backend == "petsc" else 1
    unknowns, entries, per_element, solver_bytes = {}, {}, 0.0, 0.0
    solves = "move" if command == "study" else command          # a study's points are moves
    for field in FIELDS:
        if field.active(scene, solves):
            need = field.memory(grid, scene)
            unknowns[field.title] = need.unknowns
            per_element += need.bytes_per_element
            if iterative:
                # (q1q1 flow has no iterative path: the flow refuses it once built; no KeyError first)
                solver_bytes += ITERATIVE_BYTES_PER_UNKNOWN.get(need.fill, ITERATIVE_BYTES_PER_UNKNOWN["flow"]) \
                    * need.unknowns
            else:
                entries[field.title] = factor_entries(need.unknowns, need.fill)
    if not iterative:
        solver_bytes = BACKEND_FACTOR.get(backend, 1.0) * BYTES_PER_FACTOR_ENTRY * sum(entries.values()) / split
    factor = COMMAND_FACTOR.get(command, 1.0)
    design = FILTER_BYTES_PER_ELEMENT * grid.elements if command in ("optimize", "check-gradients") else 0.0
    peak = BASE_BYTES + factor * (per_element * grid.elements + solver_bytes) + design
    return Estimate(grid.elements, unknowns, entries, peak, "iterative" if iterative else "direct", ranks)


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


def check(scene, command: str, max_memory_gb: float | None = None, jobs: int = 1) -> Estimate:
    """Refuse (InputError, exit 2) a run whose estimate exceeds the limit (``jobs``: worker
    processes of ``tofsi study``, each with its own model).

    The limit is ``max_memory_gb`` (``--max-memory``), else the scene's
    ``solver.max_memory_gb``, else the memory available now.
    """
    from tofsi.linalg.backends import requested, resolve
    backend = requested(scene.solver.linear_solver)
    if backend != "iterative":
        try:
            backend = resolve(backend)
        except InputError:
            pass                                 # reported where the backend is configured
    est = estimate(scene, command, backend, mpi_ranks())
    limit_gb = max_memory_gb or scene.solver.max_memory_gb or available_bytes() / GB
    jobs = max(int(jobs or 1), 1)
    if est.total_gb * jobs > limit_gb:
        parts = ", ".join(f"{k} {v:,} unknowns" for k, v in est.unknowns.items())
        how = ("iterative solvers" if backend == "iterative" else
               "the mesh alone" if command == "mesh" else f"sparse LU by {backend}")
        ranks = (f" on {est.ranks} ranks" if est.ranks > 1 else "") + (f" in {jobs} processes" if jobs > 1 else "")
        raise InputError("mesh.h_min", scene.mesh.h_min,
                         f"the {command} needs about {est.total_gb * jobs:.1f} GB{ranks} ({est.elements:,} elements"
                         f"{'; ' + parts if parts else ''}; {how}) but {limit_gb:.1f} GB are allowed; "
                         "use a larger mesh.h_min/h_max, or raise --max-memory / solver.max_memory_gb")
    return est
