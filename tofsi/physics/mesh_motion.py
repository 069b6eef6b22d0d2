"""Mesh motion: a scene's mover between the structure and the fluid mesh.

The one entry point for moving a scene's fluid mesh, used by the coupled
model (the field ``x``, :mod:`tofsi.fields.motion`) and by the mesh-motion
studies (:mod:`tofsi.coupling.motion`). Two forms, chosen by the scene:

* explicit interface (scenes without a design region): the non-solid quads
  move; every solid node follows the structure (``x = u``) and every channel
  boundary node stays (``x = 0``);
* density-blended (design scenes): every quad moves, the channel boundary
  stays, and an interior node ``i`` blends mover and structure with the solid
  indicator ``s_i = 1 - prod_{e at i} (1 - h(rho_e))``, ``h`` a smooth step from
  0 at rho = 0 to 1 at ``rho = r = mover.follow_density`` (see
  :mod:`movers.blend`, :mod:`tofsi.physics.indicators`): ``s_i = 1`` exactly
  as soon as one neighbouring element has ``rho >= r`` -- the mesh node then
  moves with the structure, ``x_i = u_i``, to round-off, whatever the mover's
  forces -- 0 when all are fluid, twice differentiable in between, so the
  form reduces to the explicit one for 0/1 densities and is differentiable in
  rho. (A threshold below 1 matters at large motion: with ``s`` merely near 1
  on a gray boundary a stiffened nonlinear mover's forces, 100-200 times the
  penalty's reference scale, hold the mesh up to 30 % of the motion away from
  the structure; docs/optimization.md section 4.)

Layered stiffening factors (``mover.layers``) apply to the element layers
counted from the interface of the fixed solid, or in design scenes, with
``mover.layers_from = "density"`` (the default), to the layers grown from the
densities themselves (:class:`~tofsi.physics.indicators.DensityLayers`): the
stiffening follows the evolving design and is differentiable in rho.
With ``mover.band`` only the quads of a band around the structure move, the
band's outer edge held fixed (:mod:`tofsi.mesh.band`); every map below keeps its
full size (2n), the nodes outside the band being fixed ones.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

import movers
from movers.base import MoveResult
from movers.problem import MotionProblem
from tofsi.mesh.band import find_band
from tofsi.core.kept import Kept, input_key
from tofsi.mesh.layers import element_layers, stiffening_field
from tofsi.linalg import LinearAlgebra
from tofsi.linalg.backends import resolve
from tofsi.mesh.structured import FLUID, SOLID
from tofsi.physics.indicators import DensityLayers, solid_indicator

__all__ = ["MeshMotion", "solid_indicator"]

LAYERS_SHOWN = 10          # element layers counted (and written to outputs) at least


class MeshMotion:
    """A scene's mover applied to its mesh, with the maps to and from the other fields."""

    def __init__(self, mesh, scene, motion_size: float | None = None, linear_algebra=None):
        """``motion_size``: the structure's largest displacement [m] when known beforehand
        (mesh-motion studies), for the automatic band width (``mover.band``);
        ``linear_algebra``: the model's :class:`~tofsi.linalg.LinearAlgebra`."""
        self.mesh = mesh
        self.linear_algebra = linear_algebra or LinearAlgebra(backend=resolve())
        self.mover = movers.mover_class(scene.mover.name)(scene.mover.options)
        self.blended = scene.has_design
        self.follow_density = scene.mover.follow_density
        boundary = mesh.boundary_nodes
        solid = mesh.region == SOLID
        self.layer = element_layers(mesh.incidence, mesh.interface_nodes, ~solid,
                                    n_layers=max(len(scene.mover.layers), LAYERS_SHOWN))
        factors = stiffening_field(self.layer, scene.mover.layers)
        self.density_layers = None
        if self.blended and scene.mover.layers and scene.mover.layers_from == "density":
            self.density_layers = DensityLayers(mesh.quads, mesh.n_nodes, scene.mover.layers)
            factors = np.ones(mesh.n_elements)             # the layers come with the densities
        if self.blended:
            moving, fixed = np.arange(mesh.n_elements), boundary
            self.follows = np.setdiff1d(np.arange(mesh.n_nodes), boundary)
            structure = mesh.region != FLUID
        else:
            moving, fixed = np.flatnonzero(~solid), np.union1d(mesh.nodes_of(SOLID), boundary)
            self.follows = np.setdiff1d(mesh.nodes_of(SOLID), boundary)
            structure = solid
        self.movable = moving                    # the quads the full-domain form moves
        movable = np.zeros(mesh.n_elements, dtype=bool)
        movable[moving] = True
        self.band = find_band(mesh, movable, structure, scene.mover.band, motion_size)
        if self.band is not None:                # only the band moves; its outer edge stays
            moving = np.flatnonzero(self.band.elements)
            fixed = np.union1d(fixed, self.band.edge_nodes)
            self.follows = np.setdiff1d(self.follows, self.band.outside_nodes)
        self.moving = moving
        self.base = MotionProblem.from_mesh(mesh, moving, fixed, factors[moving],
                                            linear_algebra=self.linear_algebra)
        self.kept_problem = Kept()                # the problem of the last densities
        self.kept_blend = Kept()                  # and its blend, built on first use
        self.kept_solvers = Kept()                # and a mover in increments' factorizations

    @property
    def path_dependent(self) -> bool:
        """True when the mover has no residual form (increments on the updated mesh)."""
        return self.mover.path_dependent

    @property
    def takes_tolerance(self) -> bool:
        """True when the mover's ``move`` takes ``tol``, a looser Newton tolerance (the Yeoh mover)."""
        return self.mover.takes_tolerance

    @property
    def fixed_dofs(self) -> np.ndarray:
        """Dofs of the nodes whose motion is prescribed (boundary, and solid in the explicit form)."""
        return self.base.fixed_dofs

    # ---- maps between fields ------------------------------------------------------
    def density_key(self, rho) -> tuple:
        """The key of what depends on the densities alone (everything else it reads -- mesh,
        mover, layers, band -- is fixed when the motion is built)."""
        return input_key(None if rho is None or not self.blended else np.asarray(rho))

    def problem(self, rho=None) -> MotionProblem:
        """The mover's problem for densities ``rho`` (blended form) or the fixed regions. The last
        densities' is kept, keyed by ``rho``, so a Newton's residual checks at one design do not
        rebuild the indicator and the density layers each time."""
        return self.kept_problem.get(self.density_key(rho), lambda: self._problem(rho))

    def _problem(self, rho) -> MotionProblem:
        if not self.blended:
            return self.base
        s, _ = solid_indicator(rho, self.mesh.quads, self.mesh.n_nodes, self.follow_density)
        if self.density_layers is None:
            return self.base.with_data(blend=s)
        return self.base.with_data(blend=s, stiffening=self.density_layers.factors(rho)[self.moving])

    def _at_density(self, rho):
        """``(problem, blend)`` for densities ``rho``, for the residual-form maps (the blend's
        reference stiffness kept like the problem, built on first use)."""
        problem = self.problem(rho)
        return problem, self.kept_blend.get(self.density_key(rho), lambda: self.mover.blend(problem))

    def target(self, u: np.ndarray) -> np.ndarray:
        """The motion the mover is given ``(n, 2)``: the structure's where nodes follow it, else 0."""
        t = np.zeros((self.mesh.n_nodes, 2))
        t[self.follows] = np.asarray(u).reshape(-1, 2)[self.follows]
        return t

    def target_transpose(self, t_bar: np.ndarray) -> np.ndarray:
        """Adjoint of :meth:`target`: ``(2n,)`` on ``u``."""
        u_bar = np.zeros((self.mesh.n_nodes, 2))
        u_bar[self.follows] = np.asarray(t_bar).reshape(-1, 2)[self.follows]
        return u_bar.ravel()

    def density_transpose(self, rho, s_bar: np.ndarray, f_bar: np.ndarray | None = None) -> np.ndarray:
        """Chain the blend's adjoint ``s_bar`` (n,) and the stiffening factors' ``f_bar`` (per
        moving quad) to ``rho_bar (E,)`` (fixed-solid layers do not depend on rho)."""
        if not self.blended:
            return np.zeros(self.mesh.n_elements)
        _, ds = solid_indicator(rho, self.mesh.quads, self.mesh.n_nodes, self.follow_density)
        rho_bar = ds.T @ s_bar
        if self.density_layers is not None and f_bar is not None:
            full = np.zeros(self.mesh.n_elements)
            full[self.moving] = f_bar
            rho_bar = rho_bar + self.density_layers.transpose(rho, full)
        return rho_bar

    def interface_gap(self, x, u, rho=None) -> float:
        """``max |x_i - u_i|`` [m] over the solid's nodes that follow the structure (not on the
        channel's boundary or outside the band) of elements with ``rho >= 1/2`` (the fixed solid
        where ``rho`` is None): how far the fluid mesh leaves the structure where the flow sees
        solid (0 to round-off when ``mover.follow_density <= 1/2``)."""
        solid = (self.mesh.region == SOLID) if rho is None else np.asarray(rho) >= 0.5
        nodes = np.intersect1d(np.unique(self.mesh.quads[solid]), self.follows)
        if nodes.size == 0:
            return 0.0
        gap = np.asarray(x).reshape(-1, 2)[nodes] - np.asarray(u).reshape(-1, 2)[nodes]
        return float(np.linalg.norm(gap, axis=1).max())

    # ---- moving and derivatives ------------------------------------------------------
    def move(self, u, rho=None, progress=None, initial=None, solver=None, tol=None) -> MoveResult:
        """Move the mesh with the structure's displacement ``u``: the mover's result, whose
        ``displacement`` ``(n, 2)`` is the mesh displacement ``x``. For movers that warm
        start: ``initial``, a mesh displacement for a nearby motion to start from, and
        ``solver``, an earlier move's solver to recycle (neither changes the result). For movers
        that take one (:attr:`takes_tolerance`): ``tol``, a looser Newton tolerance (a sweep
        that only starts a coupled Newton)."""
        problem = self.problem(rho)
        if solver is None:                        # the last densities' moves' factorizations, if kept
            solver = self.kept_solvers.get(self.density_key(rho), lambda: self.mover.increment_solvers(problem))
        start = {"initial": initial, "solver": solver} if self.mover.warm_starts else {}
        if tol is not None and self.takes_tolerance:
            start["tol"] = tol
        result = self.mover.move(problem, self.target(u), progress, **start)
        result.problem = problem
        return result

    def vjp(self, result: MoveResult, x_bar, rho=None):
        """``(u_bar (2n,), rho_bar (E,))`` for ``x_bar`` on the mesh displacement."""
        t_bar, f_bar, s_bar = self.mover.vjp(result.problem, result, x_bar)
        return self.target_transpose(t_bar), self.density_transpose(rho, s_bar, f_bar)

    def structure_vjp(self, result: MoveResult, x_bar) -> np.ndarray:
        """``u_bar`` (2n,) alone for ``x_bar`` on the mesh displacement (the coupling ``dx/du``'s
        transposed product: the densities' share, :meth:`density_transpose`, is not made)."""
        return self.target_transpose(self.mover.vjp(result.problem, result, x_bar)[0])

    def jvp(self, result: MoveResult, u_dot) -> np.ndarray:
        """``x_dot`` (2n,) for a change ``u_dot`` of the structure's displacement, the densities
        held (path-dependent movers: the tangent sweep through the move ``result``)."""
        return self.mover.jvp(result.problem, result, self.target(u_dot)).ravel()

    def residual(self, x, u, rho=None, jacobian: bool = True):
        """``D (2n,)`` and ``D_x`` (true Jacobian; None without ``jacobian``) for residual movers."""
        problem, blend = self._at_density(rho)
        return self.mover.residual(problem, x, self.target(u), blend=blend, jacobian=jacobian)

    def structure_partial(self, rho=None) -> sp.csr_matrix:
        """``D_u`` (2n x 2n): ``-(P_p + S_c)`` restricted to the nodes that follow the structure."""
        problem, blend = self._at_density(rho)
        diag = np.zeros(2 * self.mesh.n_nodes)
        follow_dofs = np.ravel(2 * self.follows[:, None] + np.arange(2))
        fixed = problem.bc.is_fixed
        diag[follow_dofs[fixed[follow_dofs]]] = -1.0
        if blend is not None:
            free = follow_dofs[~fixed[follow_dofs]]
            diag[free] = -blend.diag[free]
        return sp.diags(diag).tocsr()

    def partials_transpose(self, x, u, rho, lam):
        """``lam^T D_u`` (2n,) and ``lam^T D_rho`` (E,) for residual movers (no solve)."""
        problem, blend = self._at_density(rho)
        t_bar, f_bar, s_bar = self.mover.residual_partials(problem, x, self.target(u), lam, blend=blend)
        return self.target_transpose(t_bar), self.density_transpose(rho, s_bar, f_bar)

    def transposed_solve(self, x, rho, rhs, solver=None) -> np.ndarray:
        """``D_x^-T rhs`` at ``x`` (residual movers); ``solver`` from the forward move."""
        problem, blend = self._at_density(rho)
        lam, lam_p = self.mover.transposed_solve(problem, x, rhs, solver, blend=blend)
        return lam + lam_p
