"""The serial flow's element kernels on one rank's slab: the fluid load and the coupling partials by slabs.

Two-way FSI couples the distributed flow to the structure and the mesh motion
through element sums over the flow's elements: the fluid load ``f(w, x, rho)``
on the Q1 nodes, its transposed partials ``(df/dw)^T lam``, ``(df/dx)^T lam``
and ``df_e/drho_e``, and the flow's shape derivative ``F_x^T lam``. Each rank
evaluates them on *its own elements* with the serial code itself:

* :class:`SlabFlow` is a :class:`tofsi.physics.flow.Flow` whose elements are the
  slab's (its ``mesh.quads`` and ``dofs`` the slab's rows of the whole flow's; the
  whole mesh's points, dof numbering and boundary operator), so every element method of
  ``Flow`` -- residuals, Jacobian chunks, shape derivatives, friction partials -- runs
  on the slab unchanged, reading a whole-length state ``w`` (in the flow's numbering)
  whose slab entries are set (:meth:`SlabCoupling.whole`) and densities ``rho[slab]``;
* :class:`tofsi.physics.fluid_load.FluidForce` on a ``SlabFlow`` gives the slab's part
  of the load and of its partials (its element loads are the slab's, assembled on the
  whole Q1 numbering).

A nodal sum over elements is then the sum over ranks of the slabs' sums
(:meth:`SlabCoupling.allsum`: a reduction to rank 0 and a broadcast, so every rank
holds bit-identical replicated ``(2n,)`` vectors and takes the same decisions); a
sum onto the flow's dofs becomes a distributed vector
(:meth:`~tofsi.parallel.flow_system.DistributedFlow.vector_of_ghosts`).
"""

from __future__ import annotations

import numpy as np

from tofsi.core.kept import Kept
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.physics.flow import Flow
from tofsi.physics.fluid_load import FluidForce


class SlabMesh:
    """The slab's quads ``(E_r, 4)`` on the whole mesh's points (what a Flow's element methods read)."""

    def __init__(self, mesh, elements: np.ndarray):
        self.points, self.quads = mesh.points, mesh.quads[elements]
        self.n_nodes, self.n_elements = mesh.n_nodes, len(elements)


class SlabFlow(Flow):
    """The whole ``flow`` restricted to ``elements``: its element methods on those elements only
    (densities ``rho[elements]``, states in the whole flow's numbering). It is never solved or
    assembled into a matrix (its dof numbering is the whole flow's)."""

    def __init__(self, flow: Flow, elements: np.ndarray):     # not Flow's: the whole flow's maps, no new mesh
        if flow.body_force is not None:
            raise ValueError("the distributed flow has no body force term")
        self.whole, self.elements = flow, np.asarray(elements)
        self.mesh = SlabMesh(flow.mesh, self.elements)
        self.settings, self.element, self.linear_algebra = flow.settings, flow.element, flow.linear_algebra
        self.density, self.symmetric, self.body_force = flow.density, flow.symmetric, None
        self.keep_element_jacobians = False
        self.n_velocity, self.size = flow.n_velocity, flow.size
        self.dofs = flow.dofs[self.elements]                       # (E_r, m), the whole numbering
        self.boundary, self.open_outlet, self.values, self.bc = flow.boundary, flow.open_outlet, flow.values, flow.bc
        self.kept_shape, self.kept_elements, self.kept_residuals = Kept(), Kept(), Kept()
        self.kept_scale, self.kept_basis = Kept(), Kept()

    def factorize(self, A):
        raise TypeError("a SlabFlow is not solved: the distributed flow solves the whole flow")


class SlabCoupling:
    """The fluid load of ``structure`` (its form) and the coupling partials on the slab of ``engine``
    (a :class:`~tofsi.parallel.flow_system.DistributedFlow`), summed over ranks."""

    def __init__(self, engine, structure):
        self.engine, self.mpi = engine, engine.comm.tompi4py()
        p = engine.part
        self.elements = p.elements
        self.flow = SlabFlow(engine.flow, p.elements)
        self.force = FluidForce(self.flow, structure.force.form)
        self.q1_dofs = element_dofs(self.flow.mesh.quads, 2)                       # (E_r, 8)
        self.n_q1 = 2 * engine.flow.mesh.n_nodes
        old_of_new = np.empty_like(p.new_of_old)
        old_of_new[p.new_of_old] = np.arange(old_of_new.size)
        self.ghosts_old = old_of_new[engine.ghosts]                                 # (m,) whole numbering

    # ---- sums over ranks --------------------------------------------------------------
    def allsum(self, local: np.ndarray) -> np.ndarray:
        """The sum over ranks of ``local``, the same bits on every rank (reduce, then broadcast)."""
        from mpi4py import MPI
        local = np.ascontiguousarray(local, dtype=float)
        total = np.empty_like(local)
        self.mpi.Reduce(local, total, op=MPI.SUM, root=0)
        self.mpi.Bcast(total, root=0)
        return total

    def per_element(self, values: np.ndarray) -> np.ndarray:
        """The whole ``(E,)`` vector of the slabs' element values ``(E_r,)``."""
        local = np.zeros(self.engine.flow.mesh.n_elements)
        local[self.elements] = values
        return self.allsum(local)

    def whole(self, v) -> np.ndarray:
        """A whole-length vector in the flow's numbering holding the distributed ``v``'s entries
        at every dof the slab's elements touch (zero elsewhere)."""
        out = np.zeros(self.engine.flow.size)
        out[self.ghosts_old] = self.engine.ghost_values(v)
        return out

    def distributed(self, whole_local: np.ndarray):
        """The distributed vector of the slabs' sums onto the flow's dofs (each rank's ``(size,)``
        whole-numbered partial sum, nonzero on its slab's dofs only)."""
        return self.engine.vector_of_ghosts(whole_local[self.ghosts_old])

    # ---- the load and its partials ----------------------------------------------------------
    def load(self, w, x, rho, params) -> np.ndarray:
        """``f (2n,)`` at the whole-length ``w`` (:meth:`whole`), the same on every rank."""
        return self.allsum(self.force.load(w, x, rho[self.elements], params))

    def load_density(self, w, x, rho, params, lam) -> np.ndarray:
        """``(df/drho)^T lam`` ``(E,)``."""
        vectors = self.force.density_vectors(w, x, rho[self.elements], params)            # (E_r, 8)
        return self.per_element(np.einsum("ea,ea->e", vectors, lam[self.q1_dofs]))

    def load_fluid_transpose(self, w, x, rho, params, lam):
        """``(df/dw)^T lam`` as a distributed vector."""
        return self.distributed(self.force.fluid_partial_transpose(lam, w, x, rho[self.elements], params))

    def load_shape_transpose(self, w, x, rho, params, lam) -> np.ndarray:
        """``(df/dx)^T lam`` ``(2n,)``."""
        return self.allsum(self.force.shape_partial_transpose(lam, w, x, rho[self.elements], params))

    # ---- the flow's partials -----------------------------------------------------------------
    def flow_shape_transpose(self, w, x, rho, params, lam_whole) -> np.ndarray:
        """``F_x^T lam`` ``(2n,)`` (``lam`` whole-length, zero on the fixed dofs)."""
        dR = self.flow.shape_elements(w, x, rho[self.elements], params)[1]                # (E_r, m, 8)
        local = np.einsum("eab,ea->eb", dR, lam_whole[self.flow.dofs])
        return self.allsum(assemble_vector(self.q1_dofs, local, self.n_q1))

    def flow_density(self, w, x, rho, params, lam_whole) -> np.ndarray:
        """``F_rho^T lam`` ``(E,)``."""
        vectors = self.flow.density_vectors(w, x, rho[self.elements], params)            # (E_r, m)
        return self.per_element(np.einsum("ea,ea->e", vectors, lam_whole[self.flow.dofs]))
