"""The small-strain structure assembled by slabs and factorized across ranks (PETSc, MUMPS).

``K_s(rho) = sum_e E(rho_e) K0_e`` (the serial :class:`~tofsi.physics.materials.SmallStrain`'s
element matrices, ``Structure.K0``, and modulus interpolation ``Structure.simp``): each rank
adds its own slab's elements (the flow's slabs: :class:`~tofsi.parallel.partition.SlabPartition`)
into a distributed AIJ matrix, preallocated exactly, whose rows are the Q1 dofs renumbered
rank by rank (a node's dofs belong to the slab of its element column, a node on a cut to the
slab on its right). The clamped rows and columns are eliminated (``zeroRowsColumns``,
identity on the diagonal) as :class:`tofsi.fem.dirichlet.DirichletOperator` does serially.
MUMPS factorizes it across the ranks once per design (``K_s`` depends on ``rho`` and the
penalty only) and the factors serve every sweep of a two-way solve and every transposed solve
of its adjoint (``K_s`` is symmetric; the transposed solve is MUMPS's own).

Right-hand sides and solutions are the replicated ``(2n,)`` vectors the coupled solve reads
(the structure's numbering, the same bits on every rank): each rank sets its owned entries,
and the solution is gathered to every rank.
"""

from __future__ import annotations

import numpy as np

from tofsi.parallel.partition import column_cuts, rank_numbering, row_counts


class SlabStructure:
    """``K_s(rho)`` of ``structure`` by the slabs of ``engine``'s partition, solved with MUMPS."""

    def __init__(self, structure, engine):
        from petsc4py import PETSc
        self.structure, self.comm = structure, engine.comm
        mesh, part = structure.mesh, engine.part
        cuts = column_cuts(mesh.nx, part.ranks)
        owner_of_column = np.searchsorted(cuts, np.arange(mesh.nx), side="right") - 1
        node_owner = owner_of_column[np.minimum(mesh.grid_positions()[:, 0] // 2, mesh.nx - 1)]
        self.new_of_old, ranges = rank_numbering(np.repeat(node_owner, 2), part.ranks)
        self.old_of_new = np.empty_like(self.new_of_old)
        self.old_of_new[self.new_of_old] = np.arange(self.new_of_old.size)
        self.lo, self.hi = int(ranges[part.rank]), int(ranges[part.rank + 1])
        self.elements = part.elements
        self.dofs = self.new_of_old[structure.dofs[part.elements]].astype(PETSc.IntType)   # (E_r, 8)
        fixed = self.new_of_old[structure.bc.fixed]
        self.fixed_owned = np.sort(fixed[(fixed >= self.lo) & (fixed < self.hi)]).astype(PETSc.IntType)
        n, m = structure.size, self.hi - self.lo
        self.mat = PETSc.Mat().createAIJ(((m, n), (m, n)), comm=self.comm)
        self.mat.setPreallocationNNZ(row_counts(self.new_of_old[structure.dofs[part.halo_elements]],
                                                self.lo, self.hi, n))
        self.mat.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        self.b, self.x = self.mat.createVecLeft(), self.mat.createVecRight()
        self.gather, self.whole = PETSc.Scatter.toAll(self.x)
        self.ksp = None
        self.factored_at = None                  # (rho, simp) of the factors

    def factorize(self, rho, simp) -> None:
        """Assemble ``K_s`` at ``rho`` (E,) and the modulus interpolation ``simp``, and its LU
        (MUMPS, across the ranks); kept while ``(rho, simp)`` stay the same."""
        if (self.factored_at is not None and self.factored_at[1] == simp
                and np.array_equal(self.factored_at[0], rho)):
            return
        from petsc4py import PETSc
        e = self.elements
        Ke = self.structure.K0[e] * simp(np.asarray(rho)[e])[:, None, None]                # (E_r, 8, 8)
        self.mat.zeroEntries()
        self.mat.setValuesRCV(self.dofs, self.dofs, Ke, addv=PETSc.InsertMode.ADD_VALUES)
        self.mat.assemble()
        self.mat.zeroRowsColumns(self.fixed_owned, diag=1.0)
        if self.ksp is None:
            self.ksp = PETSc.KSP().create(comm=self.comm)
            self.ksp.setType("preonly")
            self.ksp.getPC().setType("lu")
            self.ksp.getPC().setFactorSolverType("mumps")
        self.ksp.setOperators(self.mat)
        self.ksp.setUp()
        self.factored_at = (np.array(rho, dtype=float), simp)

    def _solve(self, b: np.ndarray, transpose: bool) -> np.ndarray:
        from petsc4py import PETSc
        self.b.setArray(np.asarray(b, dtype=float)[self.old_of_new[self.lo:self.hi]])
        self.b.getArray()[self.fixed_owned - self.lo] = 0.0             # homogeneous: u = 0 there
        (self.ksp.solveTranspose if transpose else self.ksp.solve)(self.b, self.x)
        self.gather.scatter(self.x, self.whole, PETSc.InsertMode.INSERT_VALUES, PETSc.ScatterMode.FORWARD)
        return self.whole.getArray()[self.new_of_old].copy()

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``K_s^-1 b`` (2n,) on the free dofs, zero on the clamped ones, on every rank."""
        return self._solve(b, False)

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        """``K_s^-T b`` (2n,), zero on the clamped dofs."""
        return self._solve(b, True)
