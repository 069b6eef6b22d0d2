"""The structure block S(u; w, x, rho) = K_s(rho) u - f(w, x, rho).

Small-strain plane-strain elasticity on Q1, over the whole channel (unified
domain): element moduli by SIMP, ``E_e = Emin + rho_e^p (E0 - Emin)``, on the
reference mesh; clamped on the scene's channel sides. The load ``f`` is the
fluid's total stress transferred in the density-weighted volume form of
:mod:`tofsi.physics.fluid_load` with weight ``Psi_e = rho_e^k``, integrated on
the moved mesh ``X + x``. ``k = 1`` is Lundgaard et al.'s choice; since a
gray element's displacement then grows like ``rho^(1 - p)`` as it empties,
``k = p`` keeps it bounded (robust two-way coupling).

Blocks for the coupled Newton and the adjoint: ``S_u = K_s`` (constrained),
``S_w = -Psi B``, ``S_x = -df/dx`` (complex step through the load kernel) and
``S_rho = dK/drho u - Psi' B w``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tofsi.errors import InputError
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.interpolation import SIMP
from tofsi.linalg import DirectSolver, nested_dissection
from tofsi.physics.elasticity import element_stiffness, lame
from tofsi.physics.fluid_load import load_operator

COMPLEX_STEP = 1e-30


class Structure:
    """Linear elasticity of the unified domain, loaded by a :class:`~tofsi.physics.flow.Flow`."""

    def __init__(self, mesh, settings, flow=None, penalty: float | None = None):
        self.mesh, self.settings, self.flow = mesh, settings, flow
        self.simp = SIMP(settings.youngs_modulus, settings.e_min_ratio * settings.youngs_modulus,
                         settings.simp_penalty if penalty is None else penalty)
        self.dofs = element_dofs(mesh.quads, 2)
        self.size = 2 * mesh.n_nodes
        clamped = np.unique(np.concatenate([mesh.side_nodes(s) for s in settings.clamped]))
        if clamped.size == 0:
            raise InputError("structure.clamped", list(settings.clamped), "no side to clamp")
        self.bc = DirichletOperator(self.dofs, self.dofs, self.size, element_dofs(clamped[:, None], 2).ravel())
        self.K0 = element_stiffness(mesh.points[mesh.quads], *lame(1.0, settings.poisson_ratio))
        i = np.tile(np.arange(mesh.nx + 1), mesh.ny + 1)
        j = np.repeat(np.arange(mesh.ny + 1), mesh.nx + 1)
        self._perm = nested_dissection(np.repeat(np.column_stack([2 * i, 2 * j]), 2, axis=0))
        self._factor = None                    # (rho bytes, solver) of the last stiffness
        self._loads = None                     # (x bytes, B) of the last load operators

    # ---- stiffness ---------------------------------------------------------------
    def element_matrices(self, rho) -> np.ndarray:
        return self.K0 * self.simp(rho)[:, None, None]

    def stiffness(self, rho) -> sp.csr_matrix:
        """``S_u``: the constrained stiffness ``K_s(rho)`` [N/m]."""
        return self.bc.matrix(self.element_matrices(rho))

    def solver(self, rho) -> DirectSolver:
        """The factorized ``K_s(rho)``, kept while ``rho`` does not change."""
        key = np.asarray(rho).tobytes()
        if self._factor is None or self._factor[0] != key:
            self._factor = (key, DirectSolver(self.stiffness(rho), perm=self._perm))
        return self._factor[1]

    # ---- fluid load --------------------------------------------------------------
    def weight(self, rho) -> np.ndarray:
        """Load weight ``Psi = rho^k`` per element."""
        return np.asarray(rho, dtype=float) ** self.settings.load_exponent

    def weight_derivative(self, rho) -> np.ndarray:
        k = self.settings.load_exponent
        return k * np.asarray(rho, dtype=float) ** (k - 1.0)

    def load_operators(self, x=None) -> np.ndarray:
        """``B_e`` on the mesh moved by ``x`` (kept while ``x`` does not change: one-way
        coupling computes it once per optimization)."""
        key = None if x is None else np.asarray(x).tobytes()
        if self._loads is None or self._loads[0] != key:
            self._loads = (key, load_operator(self.flow.corners(x), self.flow.settings.viscosity))
        return self._loads[1]

    def load(self, w, x=None, rho=None, B=None) -> np.ndarray:
        """Fluid load ``f`` (2n,) [N/m] on the nodes."""
        B = self.load_operators(x) if B is None else B
        fe = np.einsum("eab,eb->ea", B, w[self.flow.dofs]) * self.weight(rho)[:, None]
        return assemble_vector(self.dofs, fe, self.size)

    # ---- residual and its partials -------------------------------------------------
    def residual(self, u, w, x, rho) -> np.ndarray:
        """``S = K_s(rho) u - f(w, x, rho)`` (unconstrained)."""
        Ku = assemble_vector(self.dofs, np.einsum("eab,eb->ea", self.element_matrices(rho), u[self.dofs]), self.size)
        return Ku - self.load(w, x, rho)

    def solve(self, w, x=None, rho=None) -> np.ndarray:
        """``u`` with ``S(u) = 0`` and the clamped dofs at zero."""
        return self.solver(rho).solve(self.bc.homogenize(self.load(w, x, rho)))

    def fluid_partial(self, x, rho) -> sp.csr_matrix:
        """``S_w = -Psi B`` (2n x size of w)."""
        B = self.load_operators(x) * -self.weight(rho)[:, None, None]
        rows = np.broadcast_to(self.dofs[:, :, None], B.shape)
        cols = np.broadcast_to(self.flow.dofs[:, None, :], B.shape)
        return sp.csr_matrix((B.ravel(), (rows.ravel(), cols.ravel())), shape=(self.size, self.flow.size))

    def shape_partial(self, w, x, rho) -> sp.csr_matrix:
        """``S_x = -df/dx`` (2n x 2n), complex step through the load kernel."""
        Xe = self.flow.corners(x)
        we = w[self.flow.dofs]
        E = Xe.shape[0]
        vals = np.empty((E, 8, 8))
        for j in range(8):
            Xc = Xe.astype(complex)
            Xc[:, j // 2, j % 2] += 1j * COMPLEX_STEP
            fe = np.einsum("eab,eb->ea", load_operator(Xc, self.flow.settings.viscosity), we)
            vals[:, :, j] = -(fe.imag / COMPLEX_STEP) * self.weight(rho)[:, None]
        rows = np.broadcast_to(self.dofs[:, :, None], vals.shape)
        cols = np.broadcast_to(self.dofs[:, None, :], vals.shape)
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(self.size, self.size))

    def density_partial(self, u, w, x, rho) -> sp.csr_matrix:
        """``S_rho`` (2n x E): ``E'(rho_e) K0_e u_e - Psi'(rho_e) B_e w_e``."""
        Ku = np.einsum("eab,eb->ea", self.K0, u[self.dofs]) * self.simp.derivative(rho)[:, None]
        fe = np.einsum("eab,eb->ea", self.load_operators(x), w[self.flow.dofs]) \
            * self.weight_derivative(rho)[:, None]
        vals = Ku - fe
        E = vals.shape[0]
        return sp.csr_matrix((vals.ravel(), (self.dofs.ravel(), np.repeat(np.arange(E), 8))),
                             shape=(self.size, E))

    def figures(self, u, w, x, rho) -> dict:
        """Compliance ``f . u`` [J/m], drag and lift [N/m], largest displacement [m]."""
        f = self.load(w, x, rho)
        return {"compliance": float(f @ u), "drag": float(f[0::2].sum()), "lift": float(f[1::2].sum()),
                "max_displacement": float(np.max(np.linalg.norm(u.reshape(-1, 2), axis=1)))}
