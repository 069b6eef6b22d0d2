"""An independent reference for the fluid's force on a body: the body cut out, no slip on it.

The same channel, mesh and element type as a Brinkman computation, but the solid's elements
are removed: they contribute nothing, the velocity of every velocity node they touch is fixed
to zero (no slip on the body's boundary, its inside inert) and the pressure corners no kept
element touches are pinned. The force on the body is the residual reaction of its boundary velocity dofs,

    F_i = -sum_(a on the body's boundary) R_(a i)(w),    R from the kept (fluid) elements,

the channel walls excluded (a body standing on a wall gets no share of the wall's reaction).
This is a different formulation from the Brinkman load (no friction, no porous solid), so
the Brinkman force converging to it is an independent check.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.dirichlet import DirichletOperator


class NoSlipReference:
    """Flow of ``flow``'s channel with the elements ``solid`` (E,) bool removed."""

    def __init__(self, flow, solid):
        self.flow, mesh, el = flow, flow.mesh, flow.element
        self.keep = ~np.asarray(solid, dtype=bool)
        qv, nv = el.quads(mesh), el.n_nodes(mesh)
        in_removed = np.zeros(nv, bool)
        in_removed[qv[~self.keep].ravel()] = True
        in_kept = np.zeros(nv, bool)
        in_kept[qv[self.keep].ravel()] = True
        walls = np.zeros(nv, bool)
        for side in ("left", "right", "bottom", "top"):
            walls[el.side_nodes(mesh, side)] = True
        self.boundary = np.flatnonzero(in_removed & in_kept & ~walls)
        removed_dofs = element_dofs(np.flatnonzero(in_removed)[:, None], 2).ravel()
        p_kept = np.zeros(mesh.n_nodes, bool)
        p_kept[mesh.quads[self.keep].ravel()] = True
        kept = np.flatnonzero(self.keep)
        inc = sp.csr_matrix((np.ones(4 * kept.size), (np.repeat(np.arange(kept.size), 4),
                                                     mesh.quads[kept].ravel())), shape=(kept.size, mesh.n_nodes))
        n_parts, _ = connected_components(inc @ inc.T, directed=False)
        if n_parts != 1:
            raise ValueError("the fluid region has an enclosed cavity; remove it (geometry.holes = [])")
        fixed = [flow.bc.fixed, removed_dofs, flow.n_velocity + np.flatnonzero(~p_kept)]
        self.bc = DirichletOperator(flow.dofs, flow.dofs, flow.size, np.concatenate(fixed))
        self.values = np.where(self.bc.is_fixed, flow.values, 0.0)
        self.values[removed_dofs] = 0.0
        self.w = None

    def element_residual(self, w, jacobian=True):
        f = self.flow
        ve, pe = f.split(w)
        Re, Ke = f.element.residual(f.corners(), ve, pe, np.zeros(f.mesh.n_elements), f.density,
                                    f.settings.viscosity, f.symmetric, None, jacobian)
        k = self.keep[:, None]
        return Re * k, (None if Ke is None else Ke * k[..., None])

    def solve(self, tol=1e-12, max_iter=30):
        """Newton on the kept elements (one step for Stokes)."""
        w, scale = self.values.copy(), None
        for _ in range(max_iter):
            Re, Ke = self.element_residual(w)
            R = self.bc.homogenize(assemble_vector(self.flow.dofs, Re, self.flow.size))
            norm = np.linalg.norm(R)
            scale = norm if scale is None else scale
            if norm <= tol * scale:
                break
            dw = self.flow.factorize(self.bc.matrix(Ke)).solve(-R)
            dw[self.bc.fixed] = 0.0
            w = w + dw
        else:
            raise RuntimeError(f"no-slip Newton did not converge: |R| = {norm:.3e}")
        self.w = w
        return w

    def force(self) -> np.ndarray:
        """The fluid's force (2,) [N/m] on the body: drag, lift."""
        Re, _ = self.element_residual(self.w, jacobian=False)
        R = assemble_vector(self.flow.dofs, Re, self.flow.size)
        return -R[element_dofs(self.boundary[:, None], 2)].sum(axis=0)
