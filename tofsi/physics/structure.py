"""The structure S(u; w, x, rho) = R_int(u; rho) - f(w, x, rho): plane-strain elasticity with SIMP.

Plane-strain elasticity on Q1, over the whole channel (unified domain):
element moduli by SIMP, ``E_e = Emin + rho_e^p (E0 - Emin)``, on the
reference mesh; clamped on the scene's channel sides. ``structure.model``:
``linear`` (small strain, ``R_int = K_s(rho) u``) or ``neo-hookean`` (finite
strain, total Lagrangian, with the energy interpolation of nearly void
elements; :mod:`tofsi.physics.finite_strain`). The load ``f`` is the
fluid's force on the solid phase, :class:`~tofsi.physics.fluid_load.FluidForce`
(``structure.load``: the momentum-consistent reaction by default), on the
moved mesh ``X + x``, with the solid phase weighted by ``psi_e = rho_e^k``.
``k = 1`` is Lundgaard et al.'s choice; since a gray element's displacement
then grows like ``rho^(1 - p)`` as it empties, ``k = p`` keeps it bounded
(robust two-way coupling).

The SIMP exponent ``p`` and the load exponent ``k`` are inputs of every call
(a :class:`~tofsi.core.blocks.Continuation`), never stored state. Partial
derivatives: ``S_u = K_s`` (constrained; at finite strain the tangent at
``u``), ``S_w = -df/dw``, ``S_x = -df/dx`` (the load acts on the moved mesh:
a follower load in two-way coupling) and ``S_rho = dR_int/drho - df/drho``
(``E'(rho) K0 u`` at small strain; the ``E'(rho)`` and ``g'(rho)`` terms at
finite strain).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tofsi.core.blocks import Continuation
from tofsi.core.errors import InputError, NumericalError
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.physics.interpolation import SIMP
from tofsi.linalg import AMGSolver, DirectSolver, LinearAlgebra, nested_dissection, rigid_body_modes
from tofsi.linalg.backends import resolve
from tofsi.mesh.structured import DESIGN, SOLID
from tofsi.physics.finite_strain import FiniteStrainElasticity, FiniteStrainSolution
from tofsi.physics.fluid_load import FluidForce

AMG_TOL = 1e-10          # AMG-CG relative residual of the iterative path (the gradient's needs)


def check_held(mesh, clamped_nodes: np.ndarray, sides) -> None:
    """Every connected region of solid (or design) elements must touch a clamped node: a
    floating solid has no equilibrium under a load (an input error, not a huge displacement)."""
    from scipy.sparse.csgraph import connected_components
    solid = np.flatnonzero(np.isin(mesh.region, (SOLID, DESIGN)))
    if solid.size == 0:
        return
    inc = mesh.incidence[solid]                                      # (S, n)
    _, label = connected_components(inc @ inc.T, directed=False)
    held = np.zeros(mesh.n_nodes, dtype=bool)
    held[clamped_nodes] = True
    touches = np.asarray(inc @ held.astype(float)).ravel() > 0        # per solid element
    held_regions = np.unique(label[touches])
    floating = np.setdiff1d(np.unique(label), held_regions)
    if floating.size:
        centre = mesh.centroids[solid[label == floating[0]]].mean(axis=0)
        raise InputError("structure.clamped", list(sides),
                         f"the solid region around ({centre[0]:.3g}, {centre[1]:.3g}) m touches none of "
                         "these channel sides, so nothing holds it; clamp a side it touches (or set "
                         "effects.structure = \"none\")")


class Structure:
    """Elasticity of the unified domain, loaded by a :class:`~tofsi.physics.flow.Flow`.

    ``params`` arguments default to the settings' load exponent and the
    default SIMP exponent (:class:`~tofsi.core.blocks.Continuation`); ``linear_algebra`` is the
    model's backend (default: superlu, or the process default).
    """

    def __init__(self, mesh, settings, flow=None, linear_algebra: LinearAlgebra | None = None):
        self.mesh, self.settings, self.flow = mesh, settings, flow
        self.linear_algebra = linear_algebra or LinearAlgebra(backend=resolve())
        self.force = None if flow is None else FluidForce(flow, settings.load)
        self.E0 = settings.youngs_modulus
        self.Emin = settings.e_min_ratio * settings.youngs_modulus
        self.defaults = Continuation(load_exponent=settings.load_exponent)
        self.dofs = element_dofs(mesh.quads, 2)
        self.size = 2 * mesh.n_nodes
        clamped = np.unique(np.concatenate([mesh.side_nodes(s) for s in settings.clamped]))
        if clamped.size == 0:
            raise InputError("structure.clamped", list(settings.clamped), "no side to clamp")
        check_held(mesh, clamped, settings.clamped)
        self.bc = DirichletOperator(self.dofs, self.dofs, self.size, element_dofs(clamped[:, None], 2).ravel())
        self.K0 = element_stiffness(mesh.points[mesh.quads], *lame(1.0, settings.poisson_ratio))
        self.grid = np.repeat(mesh.grid_positions(), 2, axis=0)      # (2n, 2) fine-grid positions
        self.perm = nested_dissection(self.grid)
        self._finite_strain = None     # its precomputed operators, built when a stage first asks

    def model(self, params=None) -> str:
        """The structure model of a solve: the continuation record's stage model (a design schedule,
        ``design.structure_model``), else the settings' ``structure.model``."""
        return self._params(params).structure_model or self.settings.model

    def finite(self, params=None) -> FiniteStrainElasticity | None:
        """The finite-strain elasticity when the solve's model is neo-Hookean, else None."""
        if self.model(params) != "neo-hookean":
            return None
        if self._finite_strain is None:
            self._finite_strain = FiniteStrainElasticity(self.mesh, self.settings, self.bc, self.dofs,
                                                         self.direct, self.K0)
        return self._finite_strain

    def nonlinear(self, params=None) -> bool:
        """True at finite strain: ``S`` is nonlinear in ``u`` (its tangent depends on ``u``)."""
        return self.model(params) == "neo-hookean"

    def direct(self, A) -> DirectSolver:
        """A direct solver of a stiffness or tangent ``A`` (the model's backend, nested dissection)."""
        return self.linear_algebra.direct(A, perm=self.perm)

    def _params(self, params):
        return self.defaults if params is None else params

    # ---- stiffness ---------------------------------------------------------------
    def simp(self, params=None) -> SIMP:
        """The modulus interpolation at the SIMP exponent of ``params``."""
        return SIMP(self.E0, self.Emin, self._params(params).penalty)

    def element_matrices(self, rho, params=None) -> np.ndarray:
        return self.K0 * self.simp(params)(rho)[:, None, None]

    def stiffness(self, rho, params=None, u=None) -> sp.csr_matrix:
        """``S_u``: the constrained stiffness ``K_s(rho)`` [N/m] (at finite strain the tangent at ``u``)."""
        finite = self.finite(params)
        if finite is not None:
            return finite.tangent(u, rho, self.simp(params))
        return self.bc.matrix(self.element_matrices(rho, params))

    def factorize(self, rho, params=None, u=None) -> DirectSolver | AMGSolver:
        """The LU of ``S_u`` (nested-dissection ordering; at finite strain the tangent at ``u``),
        or on the iterative path its smoothed-aggregation hierarchy (rigid-body modes) for CG to
        1e-10 relative."""
        if self.linear_algebra.iterative:
            return AMGSolver(self.stiffness(rho, params, u), near_null=rigid_body_modes(self.mesh.points),
                             tol=AMG_TOL)
        return self.direct(self.stiffness(rho, params, u))

    # ---- fluid load --------------------------------------------------------------
    def load(self, w, x=None, rho=None, params=None) -> np.ndarray:
        """Fluid load ``f`` (2n,) [N/m] on the nodes."""
        return self.force.load(w, x, rho, self._params(params))

    # ---- residual, solve and partials ----------------------------------------------
    def residual(self, u, w, x, rho, params=None) -> np.ndarray:
        """``S = R_int(u; rho) - f(w, x, rho)`` (unconstrained); at finite strain an element that
        inverts raises :class:`~tofsi.core.errors.NumericalError`."""
        finite = self.finite(params)
        if finite is not None:
            return finite.internal_forces(u, rho, self.simp(params)) - self.load(w, x, rho, params)
        Ke = self.element_matrices(rho, params)
        Ku = assemble_vector(self.dofs, np.einsum("eab,eb->ea", Ke, u[self.dofs]), self.size)
        return Ku - self.load(w, x, rho, params)

    def solve(self, w, x=None, rho=None, params=None, factor: DirectSolver | None = None) -> np.ndarray:
        """``u`` with ``S(u) = 0`` and the clamped dofs at zero (``factor``: the LU of
        ``K_s(rho)`` at these ``params``, if already made; at finite strain
        :meth:`newton_solve` from zero)."""
        if self.nonlinear(params):
            return self.newton_solve(w, x, rho, params).u
        factor = self.factorize(rho, params) if factor is None else factor
        return factor.solve(self.bc.homogenize(self.load(w, x, rho, params)))

    def newton_solve(self, w, x=None, rho=None, params=None, guess=None, solver=None) -> FiniteStrainSolution:
        """Finite strain: Newton with load steps, cutback and line search
        (:meth:`~tofsi.physics.finite_strain.FiniteStrainElasticity.solve`), from ``guess`` if
        given; ``solver`` a recycling solver whose factorization may precondition this solve."""
        return self.finite(params).solve(self.load(w, x, rho, params), rho, self.simp(params), guess, solver)

    def displacement_beyond_channel(self, u) -> str:
        """A sentence if the largest displacement exceeds the channel's extent (a structure
        far too soft for small-strain elasticity), else ``""``."""
        largest = float(np.max(np.linalg.norm(u.reshape(-1, 2), axis=1)))
        extent = float(np.ptp(self.mesh.points, axis=0).max())
        if largest <= extent:
            return ""
        return f"structure: displacement {largest:.3g} m exceeds the channel ({extent:.3g} m)"

    def check_displacement(self, u) -> None:
        """A displacement larger than the channel is a failure, not a result, where the mesh
        moves with it (two-way): a structure that is not held, or far too soft."""
        beyond = self.displacement_beyond_channel(u)
        if beyond:
            raise NumericalError(beyond + ": the structure is not held by structure.clamped or is far too soft",
                                 {"max_displacement": float(np.max(np.linalg.norm(u.reshape(-1, 2), axis=1))),
                                  "channel_size": float(np.ptp(self.mesh.points, axis=0).max())})

    def fluid_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``S_w = -df/dw`` (2n x size of w) at the flow state ``w``."""
        return -self.force.fluid_partial(w, x, rho, self._params(params))

    def fluid_partial_transpose(self, lam, w, x, rho, params=None) -> np.ndarray:
        """``S_w^T lam`` (size of w) without assembling ``S_w``."""
        return -self.force.fluid_partial_transpose(lam, w, x, rho, self._params(params))

    def shape_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``S_x = -df/dx`` (2n x 2n), complex step through the load kernel."""
        return -self.force.shape_partial(w, x, rho, self._params(params))

    def density_vectors(self, u, w, x, rho, params=None) -> np.ndarray:
        """``dS_e/drho_e`` ``(E, 8)``: ``E'(rho_e) K0_e u_e - df_e/drho_e`` (at finite strain
        ``dR_int,e/drho_e`` with the ``E'(rho)`` and ``g'(rho)`` terms)."""
        finite = self.finite(params)
        if finite is not None:
            Ku = finite.density_vectors(u, rho, self.simp(params))
        else:
            Ku = np.einsum("eab,eb->ea", self.K0, u[self.dofs]) * self.simp(params).derivative(rho)[:, None]
        return Ku - self.force.density_vectors(w, x, rho, self._params(params))

    def density_partial(self, u, w, x, rho, params=None) -> sp.csr_matrix:
        """``S_rho`` (2n x E)."""
        vals = self.density_vectors(u, w, x, rho, params)
        E = vals.shape[0]
        return sp.csr_matrix((vals.ravel(), (self.dofs.ravel(), np.repeat(np.arange(E), 8))),
                             shape=(self.size, E))

    def figures(self, u, w, x, rho, params=None) -> dict:
        """Compliance ``f . u`` [J/m], the largest displacement [m] of any node, and of the solid
        (nodes of elements with ``rho >= 1/2``; nearly void elements carry the Ersatz material's
        meaningless motion, which can be larger than the structure's by metres)."""
        f = self.load(w, x, rho, params)
        size = np.linalg.norm(u.reshape(-1, 2), axis=1)
        solid = np.unique(self.mesh.quads[np.asarray(rho) >= 0.5])
        return {"compliance": float(f @ u), "max_displacement": float(size.max()),
                "max_solid_displacement": float(size[solid].max()) if solid.size else 0.0}
