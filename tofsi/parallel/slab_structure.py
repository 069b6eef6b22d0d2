"""The small-strain structure assembled by slabs and factorized across ranks (PETSc, MUMPS).

``K_s(rho) = sum_e E(rho_e) K0_e`` (the serial :class:`~tofsi.physics.materials.SmallStrain`'s
element matrices, ``Structure.K0``, and modulus interpolation ``Structure.simp``): each rank
adds its own slab's elements (the flow's slabs: :class:`~tofsi.parallel.partition.SlabPartition`)
into a distributed AIJ matrix (:class:`~tofsi.parallel.slab_matrix.SlabMatrix`: the Q1 dofs
renumbered rank by rank, exact preallocation, the clamped rows and columns eliminated as
:class:`tofsi.fem.dirichlet.DirichletOperator` does serially).
MUMPS factorizes it across the ranks once per design (``K_s`` depends on ``rho`` and the
penalty only) and the factors serve every sweep of a two-way solve and every transposed solve
of its adjoint (``K_s`` is symmetric; the transposed solve is MUMPS's own).

Right-hand sides and solutions are the replicated ``(2n,)`` vectors the coupled solve reads
(the structure's numbering, the same bits on every rank): each rank sets its owned entries,
and the solution is gathered to every rank.
"""

from __future__ import annotations

import numpy as np

from tofsi.parallel.slab_matrix import SlabMatrix


class SlabStructure:
    """``K_s(rho)`` of ``structure`` by the slabs of ``engine``'s partition, solved with MUMPS."""

    def __init__(self, structure, engine):
        self.structure, part = structure, engine.part
        self.elements = part.elements
        self.dofs = structure.dofs[part.elements]                                        # (E_r, 8)
        self.matrix = SlabMatrix(engine.comm, structure.mesh, structure.dofs[part.halo_elements],
                                 structure.bc.fixed)
        self.factored_at = None                  # (rho, simp) of the factors

    def factorize(self, rho, simp) -> None:
        """Assemble ``K_s`` at ``rho`` (E,) and the modulus interpolation ``simp``, and its LU
        (MUMPS, across the ranks); kept while ``(rho, simp)`` stay the same."""
        if (self.factored_at is not None and self.factored_at[1] == simp
                and np.array_equal(self.factored_at[0], rho)):
            return
        e = self.elements
        Ke = self.structure.K0[e] * simp(np.asarray(rho)[e])[:, None, None]                # (E_r, 8, 8)
        self.matrix.factorize(self.dofs, Ke)
        self.factored_at = (np.array(rho, dtype=float), simp)

    def _solve(self, b: np.ndarray, transpose: bool) -> np.ndarray:
        b = np.array(b, dtype=float)
        b[self.structure.bc.fixed] = 0.0                                  # homogeneous: u = 0 there
        return self.matrix.solve(b, transpose)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``K_s^-1 b`` (2n,) on the free dofs, zero on the clamped ones, on every rank."""
        return self._solve(b, False)

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        """``K_s^-T b`` (2n,), zero on the clamped dofs."""
        return self._solve(b, True)
