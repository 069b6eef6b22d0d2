"""PETSc as a backend: MUMPS's parallel LU on a PETSc AIJ matrix, distributed under ``mpiexec``.

Installed from the distribution, not from pip (see ``docs/parallel.md``): on
Debian ``apt-get install python3-petsc4py-real python3-mpi4py`` (PETSc 3.18
with MUMPS, hypre and SuperLU_dist) in a virtual environment with
``numpy<2``. Run serially it is one more direct solver; run as
``mpiexec -n N tofsi solve SCENE --set solver.linear_solver=petsc`` every
rank executes the same program, assembles the same matrix (replicated
assembly) and inserts only its own block of rows into the distributed AIJ
matrix; MUMPS factorizes and solves across the ranks, and every rank gets
the whole solution back.

Analysis once per pattern: the AIJ matrix and its KSP (``preonly`` + LU by
MUMPS) are built for a pattern; new values of the same pattern are copied
into the matrix, whose non-zero structure PETSc then knows unchanged, so
MUMPS only refactorizes (its ordering and symbolic factorization are
kept). Up to :data:`SLOTS` factorizations of one pattern are alive at once,
each in its own matrix; the transposed solve is MUMPS's (``KSPSolveTranspose``).
"""

from __future__ import annotations

import logging
import weakref

import numpy as np
import scipy.sparse as sp

from tofsi.core.errors import NumericalError

log = logging.getLogger(__name__)

SLOTS = 2
INDEX_BYTES = 4


def _petsc():
    from petsc4py import PETSc
    return PETSc


def unavailable() -> str | None:
    try:
        PETSc = _petsc()
    except ImportError as err:
        return (f"petsc4py does not import ({err}); install the distribution's package "
                "(Debian: python3-petsc4py-real) in an environment with numpy<2, see docs/parallel.md")
    if not PETSc.Sys.hasExternalPackage("mumps"):
        return "this PETSc has no MUMPS"
    return None


class Backend:
    name = "petsc"

    def __init__(self):
        self.analyses = 0
        self.factorizations = 0
        self.local_rows = 0               # rows this rank owned in the last factorization

    def analyse(self, pattern, perm):
        return Analysis(self, pattern, perm)

    def set_threads(self, n: int) -> None:
        """MUMPS runs one process per rank (parallelism through mpiexec)."""


class Slot:
    """One distributed AIJ matrix with its KSP (LU by MUMPS) for a pattern."""

    def __init__(self, pattern, comm):
        PETSc = _petsc()
        n = pattern.shape[0]
        self.mat = PETSc.Mat().create(comm=comm)
        self.mat.setSizes(((PETSc.DECIDE, n), (PETSc.DECIDE, n)))
        self.mat.setType(PETSc.Mat.Type.AIJ)
        self.mat.setUp()
        self.rstart, self.rend = self.mat.getOwnershipRange()
        ip = pattern.indptr
        self.lo, self.hi = int(ip[self.rstart]), int(ip[self.rend])
        self.local_indptr = (ip[self.rstart:self.rend + 1] - ip[self.rstart]).astype(PETSc.IntType)
        self.local_indices = pattern.indices[self.lo:self.hi].astype(PETSc.IntType)
        self.mat.setPreallocationCSR((self.local_indptr, self.local_indices))
        self.mat.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        self.ksp = PETSc.KSP().create(comm=comm)
        self.ksp.setType("preonly")
        pc = self.ksp.getPC()
        pc.setType("lu")
        pc.setFactorSolverType("mumps")
        self.owner = None

    def free(self) -> bool:
        return self.owner is None or self.owner() is None

    def factorize(self, data: np.ndarray) -> None:
        self.mat.zeroEntries()
        self.mat.setValuesCSR(self.local_indptr, self.local_indices, data[self.lo:self.hi])
        self.mat.assemble()
        self.ksp.setOperators(self.mat)
        try:
            self.ksp.setUp()                   # symbolic once, numeric every time
        except _petsc().Error as err:
            raise NumericalError(f"MUMPS factorization failed ({err})", {"size": self.mat.getSize()[0]}) from None
        status = _infog(self.ksp.getPC().getFactorMatrix(), 1)
        if status < 0:
            raise NumericalError(f"MUMPS factorization failed (INFOG(1) = {status})",
                                 {"size": self.mat.getSize()[0]})


class Analysis:
    """The pattern's PETSc matrices and KSPs (made on first use, reused for new values)."""

    def __init__(self, backend: Backend, pattern, perm=None):
        self.backend, self.pattern = backend, pattern
        self.perm = perm                       # part of the cache key; MUMPS orders by itself
        self.comm = _petsc().COMM_WORLD
        self.slots: list[Slot] = []

    def _slot(self) -> Slot:
        for slot in self.slots:
            if slot.free():
                return slot
        slot = Slot(self.pattern, self.comm)
        if self.slots:                         # a second live factorization: analysed anew
            self.backend.analyses += 1
        if len(self.slots) < SLOTS:
            self.slots.append(slot)
        return slot

    def factorize(self, A: sp.csr_matrix) -> "Factorization":
        slot = self._slot()
        slot.factorize(np.ascontiguousarray(A.data, dtype=np.float64))
        self.backend.factorizations += 1
        self.backend.local_rows = slot.rend - slot.rstart
        factor = Factorization(slot)
        slot.owner = weakref.ref(factor)
        return factor


class Factorization:
    """MUMPS factors held by a slot; ``solve(b, "N" | "T")`` returns the whole solution on every rank."""

    def __init__(self, slot: Slot):
        self.slot = slot
        F = slot.ksp.getPC().getFactorMatrix()
        self.factor_nnz = _infog(F, 29)
        used_mb = _infog(F, 22)                # total memory MUMPS used, all ranks [MB]
        self.memory_bytes = (used_mb * 2**20 if used_mb > 0
                             else self.factor_nnz * (8 + INDEX_BYTES))

    def solve(self, b: np.ndarray, trans: str = "N") -> np.ndarray:
        PETSc = _petsc()
        b = np.asarray(b)
        if np.iscomplexobj(b):
            return self.solve(b.real, trans) + 1j * self.solve(b.imag, trans)
        s = self.slot
        rhs = s.mat.createVecRight()
        rhs.setArray(np.ascontiguousarray(b[s.rstart:s.rend], dtype=np.float64))
        x = s.mat.createVecLeft()
        (s.ksp.solve if trans == "N" else s.ksp.solveTranspose)(rhs, x)
        scatter, whole = PETSc.Scatter.toAll(x)
        scatter.scatter(x, whole, PETSc.InsertMode.INSERT_VALUES, PETSc.ScatterMode.FORWARD)
        out = whole.getArray().copy()
        for obj in (scatter, whole, rhs, x):
            obj.destroy()
        return out


def _infog(F, k: int) -> int:
    """MUMPS's INFOG(k) (0 when this petsc4py cannot read it)."""
    try:
        return int(F.getMumpsInfog(k))
    except (AttributeError, Exception):      # noqa: BLE001 - older petsc4py or another factor
        return 0
