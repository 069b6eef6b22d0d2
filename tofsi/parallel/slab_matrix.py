"""A matrix on the mesh's Q1 node dofs assembled by slabs and factorized across the ranks (PETSc, MUMPS).

The structure's stiffness (:mod:`tofsi.parallel.slab_structure`) and the mesh mover's tangent
(:mod:`tofsi.parallel.slab_mover`) live on the same dofs, two per mesh node (``2 i + c``, the
serial numbering of :func:`tofsi.fem.assembly.element_dofs`). :class:`SlabMatrix` renumbers
them rank by rank (a node's dofs belong to the slab of its element column, a node on a cut to
the slab on its right: :class:`~tofsi.parallel.partition.SlabPartition`'s rule), preallocates a
distributed AIJ matrix exactly from the elements touching each rank's dofs, and per assembly
adds the slab's element matrices (one ``setValuesRCV``), an optional diagonal on the owned rows,
and eliminates the Dirichlet rows and columns (``zeroRowsColumns``, identity on the diagonal),
as :class:`tofsi.fem.dirichlet.DirichletOperator` does serially. MUMPS factorizes it across the
ranks; right-hand sides and solutions are replicated ``(2n,)`` vectors in the serial numbering
(each rank sets its owned entries; the solution is gathered to every rank).
"""

from __future__ import annotations

import numpy as np

from tofsi.parallel.partition import column_cuts, rank_numbering, row_counts

MAX_KRYLOV = 20      # GMRES iterations with earlier factors before refactorizing
STALE_AFTER = 6      # more than these: the next matrix is refactorized


def node_owners(mesh, ranks: int) -> np.ndarray:
    """``(n,)`` the rank owning each mesh node (the slab of its element column; on a cut, the right one)."""
    cuts = column_cuts(mesh.nx, ranks)
    owner_of_column = np.searchsorted(cuts, np.arange(mesh.nx), side="right") - 1
    return owner_of_column[np.minimum(mesh.grid_positions()[:, 0] // 2, mesh.nx - 1)]


class SlabMatrix:
    """A distributed matrix on the node dofs of ``mesh``, assembled from element dofs ``(E, 8)``.

    halo_dofs : element dofs (serial numbering) of every element touching a dof this rank owns
    fixed : the Dirichlet dofs (serial numbering)
    recycle : keep the factors when a later matrix is assembled (PETSc's reused preconditioner:
        no copy of the matrix they came from), so that its solve (with ``rtol``) is GMRES
        preconditioned by them (a Newton's tangents, a move's increments); without it every
        solve is exact, refactorizing where the matrix changed
    """

    def __init__(self, comm, mesh, halo_dofs: np.ndarray, fixed: np.ndarray, recycle: bool = False):
        from petsc4py import PETSc
        self.comm, rank, ranks = comm, comm.getRank(), comm.getSize()
        self.new_of_old, ranges = rank_numbering(np.repeat(node_owners(mesh, ranks), 2), ranks)
        self.old_of_new = np.empty_like(self.new_of_old)
        self.old_of_new[self.new_of_old] = np.arange(self.new_of_old.size)
        self.lo, self.hi = int(ranges[rank]), int(ranges[rank + 1])
        self.size = n = self.new_of_old.size
        fixed = self.new_of_old[np.asarray(fixed, dtype=np.int64)]
        self.fixed_owned = np.sort(fixed[(fixed >= self.lo) & (fixed < self.hi)]).astype(PETSc.IntType)
        self.rows = np.arange(self.lo, self.hi, dtype=PETSc.IntType)       # the owned rows (diagonal)
        m = self.hi - self.lo
        diagonal, off = row_counts(self.new_of_old[halo_dofs], self.lo, self.hi, n)
        self.mat = PETSc.Mat().createAIJ(((m, n), (m, n)), comm=comm)
        self.mat.setPreallocationNNZ((np.maximum(diagonal, 1), off))     # a row no element touches: its 1
        self.mat.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        self.b, self.x = self.mat.createVecLeft(), self.mat.createVecRight()
        self.gather, self.whole = PETSc.Scatter.toAll(self.x)
        self.ksp, self.recycle = None, recycle
        self.factorizations, self.krylov_iterations = 0, 0
        self.fresh, self.stale = False, False        # the factors are of the assembled matrix / worn out

    def owned(self, v: np.ndarray) -> np.ndarray:
        """The owned entries ``[lo, hi)`` (new numbering) of a replicated vector (serial numbering)."""
        return np.asarray(v)[self.old_of_new[self.lo:self.hi]]

    def assemble(self, dofs: np.ndarray, Ke: np.ndarray, diagonal: np.ndarray | None = None) -> None:
        """Assemble ``sum_e Ke_e`` over the slab's elements (dofs ``(E_r, 8)``, serial numbering)
        plus ``diag(diagonal)`` (replicated ``(2n,)``, its owned entries), the Dirichlet rows and
        columns eliminated; the factors are kept (they precondition :meth:`solve` with ``rtol``)."""
        from petsc4py import PETSc
        rows = self.new_of_old[dofs].astype(PETSc.IntType)
        self.mat.zeroEntries()
        self.mat.setValuesRCV(rows, rows, Ke, addv=PETSc.InsertMode.ADD_VALUES)
        d = np.zeros(self.rows.size) if diagonal is None else self.owned(diagonal)
        self.mat.setValuesRCV(self.rows[:, None], self.rows[:, None], d[:, None, None],
                              addv=PETSc.InsertMode.ADD_VALUES)          # every diagonal slot, kept by the LU
        self.mat.assemble()
        self.mat.zeroRowsColumns(self.fixed_owned, diag=1.0)
        self.fresh = False

    def factorize(self, dofs: np.ndarray, Ke: np.ndarray, diagonal: np.ndarray | None = None) -> None:
        """:meth:`assemble`, then the LU of the matrix (MUMPS, across the ranks)."""
        self.assemble(dofs, Ke, diagonal)
        self.refactor()

    def refactor(self) -> None:
        """The LU of the assembled matrix; with ``recycle``, later assemblies leave it alone (the
        preconditioner is reused until the next :meth:`refactor`: no copy of the matrix is kept)."""
        from petsc4py import PETSc
        if self.ksp is None:
            self.ksp = PETSc.KSP().create(comm=self.comm)
            self.ksp.getPC().setType("lu")
            self.ksp.getPC().setFactorSolverType("mumps")
            self.ksp.setOperators(self.mat)
        pc = self.ksp.getPC()
        pc.setReusePreconditioner(False)
        self.ksp.setType("preonly")
        self.ksp.setUp()
        pc.setUp()               # now: KSPSetUp may leave a set-up PC alone (seen after an expiry)
        pc.setReusePreconditioner(self.recycle)
        self.factorizations += 1
        self.fresh, self.stale = True, False

    def discard(self) -> None:
        """Drop the solver and its factors (collective): the next solve analyses and factorizes
        afresh. After a failed factorization MUMPS would otherwise keep failing, whatever the
        matrix assembled next (PETSc keeps a failed analysis for a matrix of the same pattern)."""
        self.ksp.destroy()
        self.ksp, self.fresh, self.stale = None, False, False

    def expire(self) -> None:
        """The kept factors precondition no later matrix: the next solve refactorizes (a new design)."""
        self.stale = True

    def solve(self, b: np.ndarray, transpose: bool = False, rtol: float | None = None) -> np.ndarray:
        """``A^-1 b`` (or ``A^-T b``), ``b`` and the result replicated ``(2n,)`` in the serial numbering.

        Exact (the LU of ``A``, refactorized if the factors are of an earlier matrix) without
        ``rtol``; with it, GMRES to ``rtol`` preconditioned by the kept factors (an earlier
        Newton step's), refactorizing when it needs more than :data:`MAX_KRYLOV` iterations
        (and at the next matrix when it needed more than :data:`STALE_AFTER`), as
        :class:`tofsi.linalg.RecyclingSolver` does serially."""
        from petsc4py import PETSc
        self.b.setArray(self.owned(np.asarray(b, dtype=float)))
        done = False
        if rtol is not None and self.recycle and self.ksp is not None and not self.fresh and not self.stale:
            self.ksp.setType("gmres")
            self.ksp.setPCSide(PETSc.PC.Side.RIGHT)             # rtol on the true residual
            self.ksp.setTolerances(rtol=rtol, atol=0.0, max_it=MAX_KRYLOV)
            self.ksp.setUp()                                 # the kept factors are reused
            (self.ksp.solveTranspose if transpose else self.ksp.solve)(self.b, self.x)
            its = self.ksp.getIterationNumber()
            self.krylov_iterations += its
            self.stale = its > STALE_AFTER
            done = self.ksp.getConvergedReason() > 0
        if not done:
            if not self.fresh:
                self.refactor()
            elif self.ksp.getType() != "preonly":
                self.ksp.setType("preonly")
                self.ksp.setUp()
            (self.ksp.solveTranspose if transpose else self.ksp.solve)(self.b, self.x)
        reason = self.ksp.getConvergedReason()
        if reason < 0:                               # the factorization failed (the same on every rank)
            from tofsi.core.errors import NumericalError
            self.discard()                           # MUMPS keeps a failed analysis: the next solve starts anew
            name = next((k for k, v in vars(PETSc.KSP.ConvergedReason).items() if k.isupper() and v == reason), "")
            raise NumericalError(f"solve across the ranks failed (KSP reason {reason} {name})",
                                 {"reason": int(reason), "reason_name": name})
        self.gather.scatter(self.x, self.whole, PETSc.InsertMode.INSERT_VALUES, PETSc.ScatterMode.FORWARD)
        return self.whole.getArray()[self.new_of_old].copy()
