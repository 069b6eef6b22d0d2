"""The structure S(u; w, x, rho) = K_s(rho) u - f(w, x, rho): plane-strain elasticity with SIMP.

Small-strain plane-strain elasticity on Q1, over the whole channel (unified
domain): element moduli by SIMP, ``E_e = Emin + rho_e^p (E0 - Emin)``, on the
reference mesh; clamped on the scene's channel sides. The load ``f`` is the
fluid's total stress transferred in the density-weighted volume form of
:mod:`tofsi.physics.fluid_load` with weight ``Psi_e = rho_e^k``, integrated on
the moved mesh ``X + x``. ``k = 1`` is Lundgaard et al.'s choice; since a
gray element's displacement then grows like ``rho^(1 - p)`` as it empties,
``k = p`` keeps it bounded (robust two-way coupling).

The SIMP exponent ``p`` and the load exponent ``k`` are inputs of every call
(a :class:`~tofsi.blocks.Continuation`), never stored state. Partial
derivatives: ``S_u = K_s`` (constrained), ``S_w = -Psi B``,
``S_x = -df/dx`` (complex step through the load kernel) and
``S_rho = E'(rho) K0 u - Psi' B w``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tofsi.blocks import Continuation
from tofsi.errors import InputError
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.complex_step import corner_derivatives
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.interpolation import SIMP
from tofsi.linalg import DirectSolver, nested_dissection
from tofsi.physics.fluid_load import load_operator


class Structure:
    """Linear elasticity of the unified domain, loaded by a :class:`~tofsi.physics.flow.Flow`.

    ``params`` arguments default to the settings' load exponent and the
    default SIMP exponent (:class:`~tofsi.blocks.Continuation`).
    """

    def __init__(self, mesh, settings, flow=None):
        self.mesh, self.settings, self.flow = mesh, settings, flow
        self.E0 = settings.youngs_modulus
        self.Emin = settings.e_min_ratio * settings.youngs_modulus
        self.defaults = Continuation(load_exponent=settings.load_exponent)
        self.dofs = element_dofs(mesh.quads, 2)
        self.size = 2 * mesh.n_nodes
        clamped = np.unique(np.concatenate([mesh.side_nodes(s) for s in settings.clamped]))
        if clamped.size == 0:
            raise InputError("structure.clamped", list(settings.clamped), "no side to clamp")
        self.bc = DirichletOperator(self.dofs, self.dofs, self.size, element_dofs(clamped[:, None], 2).ravel())
        self.K0 = element_stiffness(mesh.points[mesh.quads], *lame(1.0, settings.poisson_ratio))
        self.grid = np.repeat(mesh.grid_positions(), 2, axis=0)      # (2n, 2) fine-grid positions
        self.perm = nested_dissection(self.grid)
        self._loads = None                     # (x bytes, B) of the last load operators

    def _params(self, params):
        return self.defaults if params is None else params

    # ---- stiffness ---------------------------------------------------------------
    def simp(self, params=None) -> SIMP:
        """The modulus interpolation at the SIMP exponent of ``params``."""
        return SIMP(self.E0, self.Emin, self._params(params).penalty)

    def element_matrices(self, rho, params=None) -> np.ndarray:
        return self.K0 * self.simp(params)(rho)[:, None, None]

    def stiffness(self, rho, params=None) -> sp.csr_matrix:
        """``S_u``: the constrained stiffness ``K_s(rho)`` [N/m]."""
        return self.bc.matrix(self.element_matrices(rho, params))

    def factorize(self, rho, params=None) -> DirectSolver:
        """The LU of ``K_s(rho)`` (nested-dissection ordering)."""
        return DirectSolver(self.stiffness(rho, params), perm=self.perm)

    # ---- fluid load --------------------------------------------------------------
    def weight(self, rho, params=None) -> np.ndarray:
        """Load weight ``Psi = rho^k`` per element."""
        return np.asarray(rho, dtype=float) ** self._params(params).load_exponent

    def weight_derivative(self, rho, params=None) -> np.ndarray:
        k = self._params(params).load_exponent
        return k * np.asarray(rho, dtype=float) ** (k - 1.0)

    def load_operators(self, x=None) -> np.ndarray:
        """``B_e`` on the mesh moved by ``x`` (kept while ``x`` does not change: one-way
        coupling computes it once per optimization)."""
        key = None if x is None else np.asarray(x).tobytes()
        if self._loads is None or self._loads[0] != key:
            self._loads = (key, load_operator(self.flow.corners(x), self.flow.settings.viscosity))
        return self._loads[1]

    def load(self, w, x=None, rho=None, params=None, B=None) -> np.ndarray:
        """Fluid load ``f`` (2n,) [N/m] on the nodes."""
        B = self.load_operators(x) if B is None else B
        fe = np.einsum("eab,eb->ea", B, w[self.flow.dofs]) * self.weight(rho, params)[:, None]
        return assemble_vector(self.dofs, fe, self.size)

    # ---- residual, solve and partials ----------------------------------------------
    def residual(self, u, w, x, rho, params=None) -> np.ndarray:
        """``S = K_s(rho) u - f(w, x, rho)`` (unconstrained)."""
        Ke = self.element_matrices(rho, params)
        Ku = assemble_vector(self.dofs, np.einsum("eab,eb->ea", Ke, u[self.dofs]), self.size)
        return Ku - self.load(w, x, rho, params)

    def solve(self, w, x=None, rho=None, params=None, factor: DirectSolver | None = None) -> np.ndarray:
        """``u`` with ``S(u) = 0`` and the clamped dofs at zero (``factor``: the LU of
        ``K_s(rho)`` at these ``params``, if already made)."""
        factor = self.factorize(rho, params) if factor is None else factor
        return factor.solve(self.bc.homogenize(self.load(w, x, rho, params)))

    def fluid_partial(self, x, rho, params=None) -> sp.csr_matrix:
        """``S_w = -Psi B`` (2n x size of w)."""
        B = self.load_operators(x) * -self.weight(rho, params)[:, None, None]
        rows = np.broadcast_to(self.dofs[:, :, None], B.shape)
        cols = np.broadcast_to(self.flow.dofs[:, None, :], B.shape)
        return sp.csr_matrix((B.ravel(), (rows.ravel(), cols.ravel())), shape=(self.size, self.flow.size))

    def fluid_partial_transpose(self, lam, x, rho, params=None) -> np.ndarray:
        """``S_w^T lam`` (size of w) without assembling ``S_w``."""
        fe = np.einsum("eab,ea->eb", self.load_operators(x), lam[self.dofs]) * self.weight(rho, params)[:, None]
        return -assemble_vector(self.flow.dofs, fe, self.flow.size)

    def shape_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``S_x = -df/dx`` (2n x 2n), complex step through the load kernel."""
        we = w[self.flow.dofs]
        mu = self.flow.settings.viscosity
        dfe = corner_derivatives(lambda Xc: np.einsum("eab,eb->ea", load_operator(Xc, mu), we),
                                 self.flow.corners(x))                                 # (E, 8, 8)
        vals = -dfe * self.weight(rho, params)[:, None, None]
        rows = np.broadcast_to(self.dofs[:, :, None], vals.shape)
        cols = np.broadcast_to(self.dofs[:, None, :], vals.shape)
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(self.size, self.size))

    def density_vectors(self, u, w, x, rho, params=None) -> np.ndarray:
        """``dS_e/drho_e`` ``(E, 8)``: ``E'(rho_e) K0_e u_e - Psi'(rho_e) B_e w_e``."""
        Ku = np.einsum("eab,eb->ea", self.K0, u[self.dofs]) * self.simp(params).derivative(rho)[:, None]
        fe = np.einsum("eab,eb->ea", self.load_operators(x), w[self.flow.dofs]) \
            * self.weight_derivative(rho, params)[:, None]
        return Ku - fe

    def density_partial(self, u, w, x, rho, params=None) -> sp.csr_matrix:
        """``S_rho`` (2n x E)."""
        vals = self.density_vectors(u, w, x, rho, params)
        E = vals.shape[0]
        return sp.csr_matrix((vals.ravel(), (self.dofs.ravel(), np.repeat(np.arange(E), 8))),
                             shape=(self.size, E))

    def figures(self, u, w, x, rho, params=None) -> dict:
        """Compliance ``f . u`` [J/m], drag and lift [N/m], largest displacement [m]."""
        f = self.load(w, x, rho, params)
        return {"compliance": float(f @ u), "drag": float(f[0::2].sum()), "lift": float(f[1::2].sum()),
                "max_displacement": float(np.max(np.linalg.norm(u.reshape(-1, 2), axis=1)))}
