"""The structure S(u; w, x, rho) = R_int(u; rho) - f(w, x, rho): plane-strain elasticity with SIMP.

Plane-strain elasticity on Q1, over the whole channel (unified domain):
element moduli by SIMP, ``E_e = Emin + rho_e^p (E0 - Emin)``, on the
reference mesh; clamped on the scene's channel sides and named solids. The internal forces
``R_int`` are its material's (:mod:`tofsi.physics.materials`, chosen by
``structure.model`` or a stage's ``design.structure_model``): ``linear``
(small strain, ``R_int = K_s(rho) u``), ``neo-hookean`` or ``saint-venant-kirchhoff``
(finite strain, total Lagrangian, with the energy interpolation of nearly void elements;
:mod:`tofsi.physics.finite_strain`). The load ``f`` is the
fluid's force on the solid phase, :class:`~tofsi.physics.fluid_load.FluidForce`
(``structure.load``: the momentum-consistent reaction by default), on the
moved mesh ``X + x``, with the solid phase weighted by ``psi_e = rho_e^k``,
plus the solid's weight where ``structure.density`` and ``structure.gravity``
give one (:class:`~tofsi.physics.gravity.DeadLoad`, a dead load weighted by the
same ``psi``). Without a flow the weight is the only load.
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
from tofsi.core.registry import MATERIALS
from tofsi.fem.assembly import element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.physics.interpolation import SIMP
from tofsi.linalg import AMGSolver, DirectSolver, LinearAlgebra, nested_dissection
from tofsi.mesh.structured import DESIGN, SIDES, SOLID
from tofsi.physics.materials import Material
from tofsi.physics.fluid_load import FluidForce
from tofsi.physics.gravity import DeadLoad

AMG_TOL = 1e-10          # AMG-CG relative residual of the iterative path (the gradient's needs)


def held_nodes(mesh, clamped, solids=None) -> np.ndarray:
    """The nodes ``structure.clamped`` holds: those of the channel sides it names and of the
    elements of the named solids (``solids``: name -> elements, :func:`tofsi.mesh.channel.named_solids`)."""
    solids = solids or {}
    nodes = []
    for name in clamped:
        if name in SIDES:
            nodes.append(mesh.side_nodes(name))
        elif name in solids:
            nodes.append(np.unique(mesh.quads[solids[name]]))
        else:
            raise InputError("structure.clamped", name, "neither a channel side (" + ", ".join(SIDES) + ") nor a "
                             "named solid (" + (", ".join(solids) or "geometry.solid_names, geometry.circle_names")
                             + ")")
    return np.unique(np.concatenate(nodes))


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
                         "these channel sides or solids, so nothing holds it; clamp a side or a named "
                         "solid it touches (or set effects.structure = \"none\")")


class Structure:
    """Elasticity of the unified domain, loaded by a :class:`~tofsi.physics.flow.Flow`.

    ``params`` arguments default to the settings' load exponent and the
    default SIMP exponent (:class:`~tofsi.core.blocks.Continuation`); ``material`` arguments
    to the settings' ``structure.model`` (:meth:`material`); ``linear_algebra`` is the
    model's backend (default: superlu, or the process default); ``solids`` the named solids'
    elements (name -> element indices) that ``structure.clamped`` may name.
    """

    def __init__(self, mesh, settings, flow=None, linear_algebra: LinearAlgebra | None = None, solids=None):
        self.mesh, self.settings, self.flow = mesh, settings, flow
        self.linear_algebra = linear_algebra or LinearAlgebra.default()
        self.force = None if flow is None else FluidForce(flow, settings.load)
        self.weight = (DeadLoad(mesh, settings.density, settings.gravity)
                       if settings.density > 0 and any(settings.gravity) else None)
        self.E0 = settings.youngs_modulus
        self.Emin = settings.e_min_ratio * settings.youngs_modulus
        self.defaults = Continuation(load_exponent=settings.load_exponent)
        self.dofs = element_dofs(mesh.quads, 2)
        self.size = 2 * mesh.n_nodes
        clamped = held_nodes(mesh, settings.clamped, solids)
        if clamped.size == 0:
            raise InputError("structure.clamped", list(settings.clamped), "no side or solid to clamp")
        check_held(mesh, clamped, settings.clamped)
        self.bc = DirichletOperator(self.dofs, self.dofs, self.size, element_dofs(clamped[:, None], 2).ravel())
        self.K0 = element_stiffness(mesh.points[mesh.quads], *lame(1.0, settings.poisson_ratio))
        self.grid = np.repeat(mesh.grid_positions(), 2, axis=0)      # (2n, 2) fine-grid positions
        self.perm = nested_dissection(self.grid)
        self.materials: dict[str, Material] = {}   # by name, each built (its operators) when first asked

    def material(self, name: str = "") -> Material:
        """The material ``name`` (a :data:`~tofsi.core.registry.MATERIALS` entry) bound to this
        structure; ``""``: the settings' ``structure.model``."""
        name = name or self.settings.model
        if name not in self.materials:
            self.materials[name] = MATERIALS.get(name)(self)
        return self.materials[name]

    def direct(self, A) -> DirectSolver:
        """A direct solver of a stiffness or tangent ``A`` (the model's backend, nested dissection)."""
        return self.linear_algebra.direct(A, perm=self.perm)

    def linear_solver(self, A) -> DirectSolver | AMGSolver:
        """The solver of a stiffness ``A``: its LU (nested-dissection ordering), or on the
        iterative path its smoothed-aggregation hierarchy (rigid-body modes) for CG to 1e-10."""
        return self.linear_algebra.elasticity(A, self.mesh.points, self.perm, tol=AMG_TOL)

    def _params(self, params):
        return self.defaults if params is None else params

    # ---- stiffness ---------------------------------------------------------------
    def simp(self, params=None) -> SIMP:
        """The modulus interpolation at the SIMP exponent of ``params``."""
        return SIMP(self.E0, self.Emin, self._params(params).penalty)

    def stiffness(self, rho, params=None, u=None, material: Material | None = None) -> sp.csr_matrix:
        """``S_u``: the constrained stiffness ``K_s(rho)`` [N/m] (at finite strain the tangent at ``u``)."""
        return (material or self.material()).tangent(u, rho, self.simp(params))

    def factorize(self, rho, params=None, u=None, material: Material | None = None) -> DirectSolver | AMGSolver:
        """The :meth:`linear_solver` of ``S_u`` (at finite strain the tangent at ``u``)."""
        return self.linear_solver(self.stiffness(rho, params, u, material))

    # ---- fluid load --------------------------------------------------------------
    def load(self, w, x=None, rho=None, params=None) -> np.ndarray:
        """The load ``f`` (2n,) [N/m] on the nodes: the fluid's (``w`` the flow state, ``x`` the
        fluid mesh's motion) and the solid's weight."""
        f = np.zeros(self.size)
        if self.force is not None:
            f += self.force.load(w, x, rho, self._params(params))
        if self.weight is not None:
            f += self.weight.load(self._rho(rho), self._params(params))
        return f

    def load_density_vectors(self, w, x, rho, params=None) -> np.ndarray:
        """``df_e/drho_e`` ``(E, 8)`` of the whole load (fluid and weight)."""
        vals = np.zeros((self.mesh.n_elements, 8))
        if self.force is not None:
            vals += self.force.density_vectors(w, x, rho, self._params(params))
        if self.weight is not None:
            vals += self.weight.density_vectors(self._rho(rho), self._params(params))
        return vals

    def _rho(self, rho):
        return np.zeros(self.mesh.n_elements) if rho is None else rho

    # ---- residual, solve and partials ----------------------------------------------
    def residual(self, u, w, x, rho, params=None, material: Material | None = None) -> np.ndarray:
        """``S = R_int(u; rho) - f(w, x, rho)`` (unconstrained); at finite strain an element that
        inverts raises :class:`~tofsi.core.errors.NumericalError`."""
        R_int = (material or self.material()).internal_forces(u, rho, self.simp(params))
        return R_int - self.load(w, x, rho, params)

    def solve(self, w, x=None, rho=None, params=None, material: Material | None = None) -> np.ndarray:
        """``u`` with ``S(u) = 0`` and the clamped dofs at zero (at finite strain by Newton with
        load steps from zero)."""
        material = material or self.material()
        return material.solve(self.load(w, x, rho, params), rho, self.simp(params))[0]

    def displacement_beyond_channel(self, u, rho=None) -> str:
        """A sentence if the displacement ``u`` is no physical state, else ``""``: not finite;
        larger than the channel in either direction at any node (``|u_x|`` beyond its length,
        ``|u_y|`` beyond its height); or, given the densities ``rho``, a node of the solid
        (elements with ``rho >= 0.5``) moved out of the channel by more than half an element."""
        U = np.asarray(u).reshape(-1, 2)
        if not np.all(np.isfinite(U)):
            return f"structure: displacement not finite at {int(np.sum(~np.isfinite(U).all(axis=1)))} node(s)"
        points = self.mesh.points
        lo, hi = points.min(axis=0), points.max(axis=0)
        largest = np.abs(U).max(axis=0)
        over = largest / (hi - lo)
        if over.max() > 1.0:
            axis = int(np.argmax(over))
            return (f"structure: displacement {largest[axis]:.3g} m in {'xy'[axis]} exceeds the channel's "
                    f"{('length', 'height')[axis]} ({hi[axis] - lo[axis]:.3g} m)")
        if rho is None:
            return ""
        solid = np.unique(self.mesh.quads[np.asarray(rho) >= 0.5])
        if solid.size == 0:
            return ""
        moved = points[solid] + U[solid]
        outside = np.maximum(lo - moved, moved - hi).max(axis=1)
        quads = self.mesh.quads
        slack = 0.5 * float(np.linalg.norm(points[quads[:, 1]] - points[quads[:, 0]], axis=1).min())
        k = int(np.argmax(outside))
        if outside[k] <= slack:
            return ""
        (x, y), (mx, my) = points[solid[k]], moved[k]
        return (f"structure: the solid leaves the channel (its node at ({x:.3g}, {y:.3g}) m moves "
                f"{np.hypot(*U[solid[k]]):.3g} m to ({mx:.3g}, {my:.3g}) m, {outside[k]:.3g} m outside)")

    def check_displacement(self, u, rho=None) -> None:
        """A displacement that is no physical state (:meth:`displacement_beyond_channel`) is a
        failure, not a result, where the mesh moves with it (two-way): a structure that is not
        held, or far too soft."""
        beyond = self.displacement_beyond_channel(u, rho)
        if beyond:
            raise NumericalError(beyond + " (no element failed): the design is far too soft for the flow's "
                                 "load (the mesh cannot follow it)",
                                 {"max_displacement": float(np.max(np.hypot(*u.reshape(-1, 2).T))),
                                  "channel_size": np.ptp(self.mesh.points, axis=0).tolist()})

    def fluid_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``S_w = -df/dw`` (2n x size of w) at the flow state ``w``."""
        return -self.force.fluid_partial(w, x, rho, self._params(params))

    def fluid_partial_transpose(self, lam, w, x, rho, params=None) -> np.ndarray:
        """``S_w^T lam`` (size of w) without assembling ``S_w``."""
        return -self.force.fluid_partial_transpose(lam, w, x, rho, self._params(params))

    def shape_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``S_x = -df/dx`` (2n x 2n), complex step through the load kernel."""
        return -self.force.shape_partial(w, x, rho, self._params(params))

    def density_vectors(self, u, w, x, rho, params=None, material: Material | None = None) -> np.ndarray:
        """``dS_e/drho_e`` ``(E, 8)``: ``E'(rho_e) K0_e u_e - df_e/drho_e`` (fluid load and weight; at
        finite strain ``dR_int,e/drho_e`` with the ``E'(rho)`` and ``g'(rho)`` terms)."""
        R_int = (material or self.material()).density_vectors(u, rho, self.simp(params))
        return R_int - self.load_density_vectors(w, x, rho, params)

    def density_partial(self, u, w, x, rho, params=None, material: Material | None = None) -> sp.csr_matrix:
        """``S_rho`` (2n x E)."""
        vals = self.density_vectors(u, w, x, rho, params, material)
        E = vals.shape[0]
        return sp.csr_matrix((vals.ravel(), (self.dofs.ravel(), np.repeat(np.arange(E), 8))),
                             shape=(self.size, E))

    def figures(self, u, w, x, rho, params=None) -> dict:
        """Compliance ``f . u`` [J/m], the largest displacement [m] of any node, and of the solid
        (nodes of elements with ``rho >= 1/2``; nearly void elements carry the Ersatz material's
        meaningless motion, which can be larger than the structure's by metres)."""
        f = self.load(w, x, rho, params)
        size = np.hypot(*u.reshape(-1, 2).T)            # no overflow before the result does
        solid = np.unique(self.mesh.quads[np.asarray(rho) >= 0.5])
        return {"compliance": float(f @ u), "max_displacement": float(size.max()),
                "max_solid_displacement": float(size[solid].max()) if solid.size else 0.0}
