"""The fluid block F(w; x, rho): flow in the channel on the moved mesh.

``w = (v, p)``: velocity on the element type's velocity nodes (dofs ``2 k + i``;
Taylor-Hood Q2/Q1 by default, or stabilized equal-order Q1/Q1 with
``fluid.element = "q1q1"``, :mod:`tofsi.physics.fluid_elements`), then pressure
on the Q1 corners (dofs ``n_velocity + k``). The mesh is the reference mesh moved by
``x`` (n, 2) -- the ALE configuration -- and Brinkman friction
``alpha(rho_e)`` acts per element. Boundary conditions come from
:mod:`tofsi.physics.flow_boundary` (walls, parabolic inflow and outflow, open
outlets on any side; by default inflow on the left and an open right side),
where open segments take the natural condition of the viscous form
(``zero-pressure``: the do-nothing condition of the gradient form,
``traction-free``: ``sigma n = 0``) or, with ``fixed-pressure``, hold ``p = 0`` at
their nodes (topFlow's and TOFLUX's outlets). With no open boundary the
pressure is pinned at one corner.

Steady Navier-Stokes is solved by Newton's method with a backtracking line
search on ``|R|``; when it fails, by continuation in the fluid density
(Reynolds number) from Stokes flow (:mod:`tofsi.physics.flow_newton`). Every
solve reports its history and raises :class:`~tofsi.core.errors.NumericalError`
rather than return an unconverged state. The Brinkman convexity ``q`` is an input of every call
(``params``, a :class:`~tofsi.core.blocks.Continuation`); a solve creates its own
linear solver, so its result depends only on its inputs. This module holds the
discretization: the state's layout, the residual, its Jacobian and partials (each
evaluation kept, keyed by every input), the linear solver's factorizer and the figures.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tofsi.core.blocks import Continuation
from tofsi.core.errors import InputError
from tofsi.fem.assembly import SaddlePattern, SparsePattern, assemble_vector, element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.fem.geometry import map_points
from tofsi.physics.interpolation import Brinkman
from tofsi.core.kept import Kept, input_key
from tofsi.linalg import LinearAlgebra, RecyclingSolver, nested_dissection
from tofsi.physics.flow_boundary import FlowBoundary
from tofsi.physics.flow_newton import FlowReport, FlowSolution, newton_solve
from tofsi.physics.flow_preconditioner import flow_preconditioner
from tofsi.physics.fluid_elements import ELEMENTS
from tofsi.physics.flow_view import FlowCoefficients, FlowView
from tofsi.physics.fluid_kernel import CHUNK


class Flow:
    """Finite-element discretization of the channel flow on a structured mesh (the element type
    of ``settings.element``).

    mesh : StructuredQuadMesh; settings : FluidSettings; stokes : drop inertia
    boundary_velocity : optional ``v(points (m, 2)) -> (m, 2)`` prescribed on all four
        sides instead of the channel conditions (closed box; verification problems)
    body_force : optional ``f(points (E, G, 2)) -> (E, G, 2)`` [N/m^3] on the current
        configuration (complex-safe, so shape derivatives include it)
    linear_algebra : the model's :class:`~tofsi.linalg.LinearAlgebra` (default: superlu, or the
        process default)
    keep_element_jacobians : keep the last Jacobian evaluation's element matrices ``K_e``
        (``(E, m, m)``: 3.9 kB per element for Taylor-Hood) for the two-way coupling's assembled
        fluid-load partial; without it :meth:`jacobian` assembles chunk by chunk and the fluid
        load's adjoint product recomputes them chunk by chunk (:meth:`element_jacobian_chunks`)
    """

    def __init__(self, mesh, settings, stokes: bool = False, boundary_velocity=None,
                 body_force=None, linear_algebra: LinearAlgebra | None = None,
                 keep_element_jacobians: bool = False):
        self.mesh, self.settings = mesh, settings
        self.keep_element_jacobians = keep_element_jacobians
        self.linear_algebra = linear_algebra or LinearAlgebra.default()
        self.body_force = body_force
        self.density = 0.0 if stokes else settings.density
        self.symmetric = settings.outlet in ("traction-free", "fixed-pressure")
        self.element = element = ELEMENTS[settings.element]
        if self.linear_algebra.iterative and not element.block_preconditioned:
            raise InputError("fluid.element", settings.element, "q2q1 on the iterative path (its block "
                             "preconditioner is written for Taylor-Hood); q1q1 with a direct solver.backend")
        nv, n = element.n_nodes(mesh), mesh.n_nodes
        self.n_velocity, self.size = 2 * nv, 2 * nv + n
        self.dofs = np.hstack([element_dofs(element.quads(mesh), 2), 2 * nv + mesh.quads])   # (E, 2k + 4)
        self.boundary = (FlowBoundary.for_channel(mesh, settings, element) if boundary_velocity is None
                         else FlowBoundary.prescribed(mesh, boundary_velocity, element))
        self.open_outlet = self.boundary.is_open
        pressure = self.boundary.fixed_pressure if self.open_outlet else np.array([0])   # closed: pin p
        fixed = [self.boundary.fixed, self.n_velocity + pressure]
        self.values = np.zeros(self.size)
        self.values[:2 * nv] = self.boundary.values
        self.bc = DirichletOperator(self.dofs, self.dofs, self.size, np.concatenate(fixed))
        self._perm = None
        self.kept_shape = Kept()          # (R_e, dR_e/dXe) of the last shape evaluation
        self.kept_elements = Kept()       # (R_e, K_e) of the last Jacobian evaluation
        self.kept_residuals = Kept()      # R_e of the last residual-only evaluation
        self.kept_scale = Kept()          # the force scale of the last mesh position and density
        self.kept_basis = Kept()          # the element basis of the last configuration (keeps_basis)
        self._shape_pattern = None        # CSR pattern of F_x
        self._saddle_pattern = None       # the Jacobian's blocks' pattern on the iterative path

    # ---- geometry and state -------------------------------------------------------
    def corners(self, x=None) -> np.ndarray:
        """Current corner coordinates ``(E, 4, 2)`` of the mesh moved by ``x`` (n, 2)."""
        P = self.mesh.points if x is None else self.mesh.points + x
        return P[self.mesh.quads]

    def split(self, w):
        """Element velocities ``(E, k, 2)`` (``k`` velocity nodes per element) and pressures ``(E, 4)``."""
        we = w[self.dofs]
        k2 = 2 * self.element.nodes_per_element
        return we[:, :k2].reshape(len(we), -1, 2), we[:, k2:]

    def corner_velocity(self, w) -> np.ndarray:
        """The velocity ``(n, 2)`` at the corner nodes (numbered first among the velocity nodes)."""
        return np.asarray(w)[:self.n_velocity].reshape(-1, 2)[:self.mesh.n_nodes]

    def brinkman(self, params: Continuation | None = None) -> Brinkman:
        """The friction interpolation at the Brinkman ``q`` of ``params``."""
        q = Continuation().brinkman_q if params is None else params.brinkman_q
        return Brinkman(self.settings.alpha_max, self.settings.alpha_min, q)

    def alpha(self, rho, params: Continuation | None = None) -> np.ndarray:
        """Brinkman friction per element [kg/(m^3 s)]; ``rho = None`` means all fluid."""
        return self.brinkman(params)(np.zeros(self.mesh.n_elements) if rho is None else rho)

    def boundary_values(self, params: Continuation | None = None) -> np.ndarray:
        """The prescribed values (zero on free dofs) at the load of ``params`` (the inflow ramp
        of a load continuation; 1: the scene's)."""
        load = 1.0 if params is None else params.load
        return self.values if load == 1.0 else load * self.values

    def initial(self, params: Continuation | None = None) -> np.ndarray:
        """The state with the boundary values (at the load of ``params``) and zero elsewhere."""
        return self.boundary_values(params).copy()

    def basis(self, x=None):
        """The element basis of the mesh moved by ``x`` where the element type keeps it
        (:attr:`~tofsi.physics.fluid_elements.FluidElement.keeps_basis`; else None): kept per
        configuration, keyed by ``x`` (a one-way flow's Newton steps, line search, adjoint and
        objectives all read one)."""
        if not self.element.keeps_basis:
            return None
        return self.kept_basis.get(input_key(None if x is None else np.asarray(x)),
                                   lambda: self.element.basis(self.corners(x)))

    def coefficients(self, rho, params: Continuation | None = None) -> FlowCoefficients:
        """The kernels' frozen coefficients at densities ``rho`` (None: all fluid) and the stage's
        numbers ``params``."""
        brinkman = self.brinkman(params)
        alpha = brinkman(np.zeros(self.mesh.n_elements) if rho is None else rho)
        return FlowCoefficients(alpha, brinkman, self.density, self.settings.viscosity, self.symmetric)

    def view(self, w, x=None, rho=None, params: Continuation | None = None) -> FlowView:
        """The flow of state ``w`` on the mesh moved by ``x`` at densities ``rho``, as objectives
        read it (:class:`~tofsi.physics.flow_view.FlowView`, every element)."""
        rho = np.zeros(self.mesh.n_elements) if rho is None else np.asarray(rho, dtype=float)
        return FlowView(self.element, self.corners(x), np.asarray(w)[self.dofs], self.dofs, self.size, rho,
                        self.coefficients(rho, params), self.basis(x))

    # ---- residual, Jacobian, partials ---------------------------------------------
    def element_residual(self, w, x, rho, jacobian=True, density=None, Xe=None, params=None):
        """Element residuals and Jacobians on the mesh moved by ``x`` (or on corners ``Xe``)."""
        ve, pe = self.split(w)
        basis = self.basis(x) if Xe is None else None
        Xe = self.corners(x) if Xe is None else Xe
        return self.element.residual(Xe, ve, pe, self.alpha(rho, params),
                                     self.density if density is None else density,
                                     self.settings.viscosity, self.symmetric, self.force_at(Xe), jacobian, basis)

    def force_at(self, Xe):
        """The body force ``(E, G, 2)`` at the element kernel's points of corners ``Xe``, or None."""
        return None if self.body_force is None else self.body_force(map_points(Xe, self.element.POINTS))

    def residual(self, w, x=None, rho=None, density=None, params=None) -> np.ndarray:
        """``F(w; x, rho)`` (size,), unconstrained (boundary rows included)."""
        return assemble_vector(self.dofs, self.element_residuals(w, x, rho, params, density), self.size)

    def evaluation_key(self, w, x, rho, params, density=None) -> tuple:
        """The key of an element evaluation at ``(w, x, rho, params)``: every input it reads,
        the flow's own settings included (its density -- the Reynolds continuation's --, the
        outlet form, the settings record, the body force), so a kept value can never be another
        point's. ``rho = None`` is all fluid; ``density = None`` the flow's own."""
        rho = np.zeros(self.mesh.n_elements) if rho is None else np.asarray(rho)
        density = self.density if density is None else density
        return input_key(None if w is None else np.asarray(w), None if x is None else np.asarray(x), rho,
                         params, density, self.symmetric, self.settings, self.body_force)

    def element_jacobians(self, w, x=None, rho=None, params=None, density=None):
        """``(R_e (E, m), K_e (E, m, m))`` (``m = 22`` Taylor-Hood, 12 equal order) on the mesh
        moved by ``x`` (``density`` defaults to the flow's). The last evaluation is kept
        (read-only), keyed by every input: the fluid load's ``S_w`` at a converged state reuses
        the Jacobian of the Newton solve's last check."""
        return self.kept_elements.get(
            self.evaluation_key(w, x, rho, params, density),
            lambda: self.element_residual(w, x, rho, density=density, params=params))

    def element_residuals(self, w, x=None, rho=None, params=None, density=None) -> np.ndarray:
        """``R_e (E, m)`` on the mesh moved by ``x``: the kept Jacobian evaluation's when its
        inputs are these, else a residual-only evaluation, itself kept (keyed by every input), so
        a line-search trial's flow residual and the fluid load at the same state share one."""
        key = self.evaluation_key(w, x, rho, params, density)
        both = self.kept_elements.peek(key)
        if both is not None:
            return both[0]
        return self.kept_residuals.get(
            key, lambda: self.element_residual(w, x, rho, jacobian=False, density=density, params=params)[0])

    def element_jacobian_chunks(self, w, x=None, rho=None, params=None, density=None, chunk: int = CHUNK):
        """``(elements (slice), R_e, K_e)`` chunk by chunk of ``chunk`` elements (the kept
        evaluation at once where it holds these inputs): the element Jacobians without all of
        them held at a time."""
        both = self.kept_elements.peek(self.evaluation_key(w, x, rho, params, density))
        if both is not None:
            yield slice(None), both[0], both[1]
            return
        ve, pe = self.split(w)
        Xe = self.corners(x)
        alpha, force, basis = self.alpha(rho, params), self.force_at(Xe), self.basis(x)
        density = self.density if density is None else density
        for a in range(0, len(Xe), chunk):
            s = slice(a, min(a + chunk, len(Xe)))
            yield (s, *self.element.residual(Xe[s], ve[s], pe[s], alpha[s], density, self.settings.viscosity,
                                              self.symmetric, None if force is None else force[s], True,
                                              None if basis is None else (basis[0][s], basis[1][s])))

    def jacobian(self, w, x=None, rho=None, density=None, params=None):
        """``F_w`` as the constrained CSR matrix (identity on fixed dofs) and ``F``. With
        ``keep_element_jacobians`` from the kept element evaluation; else assembled chunk by
        chunk (the element matrices never all held) with the element residuals kept (keyed by
        every input) for the residuals and loads at this state."""
        if self.keep_element_jacobians:
            Re, Ke = self.element_jacobians(w, x, rho, params, density)
            return self.bc.matrix(Ke), assemble_vector(self.dofs, Re, self.size)
        pattern = self.jacobian_pattern()
        data, Re = pattern.zeros(), None
        for elements, Re_c, Ke_c in self.element_jacobian_chunks(w, x, rho, params, density):
            if Re is None:
                Re = np.empty((self.mesh.n_elements, Re_c.shape[1]), dtype=Re_c.dtype)
            Re[elements] = Re_c
            pattern.add(data, elements, Ke_c)
        Re = self.kept_residuals.get(self.evaluation_key(w, x, rho, params, density), lambda: Re)
        return pattern.matrix(data, 1.0), assemble_vector(self.dofs, Re, self.size)

    def jacobian_pattern(self):
        """The pattern :meth:`jacobian` assembles on, as the model's linear algebra lays it out
        (:meth:`~tofsi.linalg.LinearAlgebra.saddle_point_layout`): the constrained CSR matrix,
        or its blocks ``A``, ``B`` (:class:`~tofsi.fem.assembly.SaddlePattern`, made once)."""
        return self.linear_algebra.saddle_point_layout(lambda: self.bc.pattern, self._blocks_pattern)

    def _blocks_pattern(self):
        if self._saddle_pattern is None:
            self._saddle_pattern = SaddlePattern(self.bc.new_pattern(), self.n_velocity,
                                                 self.bc.is_fixed[self.n_velocity:].astype(float))
        return self._saddle_pattern

    def shape_elements(self, w, x=None, rho=None, params=None):
        """``(R_e (E, m), dR_e/dXe (E, m, 8))`` on the mesh moved by ``x``: the element type's
        (Taylor-Hood: analytic, :func:`~tofsi.physics.fluid_shape.fluid_shape`, or with a body
        force the complex step; equal order: the complex step). The last evaluation is kept,
        keyed by every input (the flow's ``F_x`` and the fluid load's ``S_x`` share it)."""
        return self.kept_shape.get(self.evaluation_key(w, x, rho, params),
                                   lambda: self._shape_elements(w, x, rho, params))

    def _shape_elements(self, w, x, rho, params):
        rho = np.zeros(self.mesh.n_elements) if rho is None else np.asarray(rho, dtype=float)
        ve, pe = self.split(w)
        return self.element.shape(self.corners(x), ve, pe, self.alpha(rho, params), self.density,
                                  self.settings.viscosity, self.symmetric,
                                  None if self.body_force is None else self.force_at)

    def shape_partial(self, w, x=None, rho=None, params=None) -> sp.csr_matrix:
        """``F_x`` (size x 2n): derivative with respect to the mesh displacement."""
        if self._shape_pattern is None:
            self._shape_pattern = SparsePattern(self.dofs, element_dofs(self.mesh.quads, 2),
                                                (self.size, 2 * self.mesh.n_nodes))
        return self._shape_pattern.assemble(self.shape_elements(w, x, rho, params)[1])

    def alpha_vectors(self, w, x, rho, params=None) -> np.ndarray:
        """``dF_e/dalpha_e`` ``(E, m)``: the element residual's derivative in its friction
        (equal order: the stabilization's too)."""
        ve, pe = self.split(w)
        Xe = self.corners(x)
        return self.element.alpha_partial(Xe, ve, pe, self.alpha(rho, params), self.density,
                                          self.settings.viscosity, self.symmetric, self.force_at(Xe),
                                          self.basis(x))

    def density_vectors(self, w, x, rho, params=None) -> np.ndarray:
        """``dF_e/drho_e`` ``(E, m)``: the Brinkman friction's derivative per element."""
        rho = np.zeros(self.mesh.n_elements) if rho is None else rho
        return self.alpha_vectors(w, x, rho, params) * self.brinkman(params).derivative(rho)[:, None]

    def density_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``F_rho`` (size x E)."""
        vals = self.density_vectors(w, x, rho, params)
        E, m = vals.shape
        return sp.csr_matrix((vals.ravel(), (self.dofs.ravel(), np.repeat(np.arange(E), m))),
                             shape=(self.size, E))

    # ---- solving -------------------------------------------------------------------
    def grid(self) -> np.ndarray:
        """Fine-grid positions of the dofs (for the nested-dissection ordering)."""
        return np.vstack([np.repeat(self.element.grid_positions(self.mesh), 2, axis=0),
                          self.mesh.grid_positions()])

    @property
    def pressure_dofs(self) -> np.ndarray:
        """(size,) bool: the pressure unknowns (numbered after the velocities in each block)."""
        return np.arange(self.size) >= self.n_velocity

    @property
    def ordering(self) -> np.ndarray:
        """The nested-dissection permutation of the dofs (pressures last per block), made once."""
        if self._perm is None:
            self._perm = nested_dissection(self.grid(), last=self.pressure_dofs)
        return self._perm

    def factorize(self, A):
        """The LU of a flow Jacobian (nested dissection, pressures last per block)."""
        return self.linear_algebra.direct(A, perm=self.ordering)

    def factorizer(self, x=None, rho=None, params=None):
        """``A -> solver`` for the flow Jacobians on the mesh moved by ``x`` with densities ``rho``:
        the LU (:meth:`factorize`), or on the iterative path the block preconditioner, whose
        Schur complement approximation reads this mesh position and this friction
        (:mod:`tofsi.physics.flow_preconditioner`)."""
        x = None if x is None else np.array(x, dtype=float)
        rho = None if rho is None else np.array(rho, dtype=float)
        return self.linear_algebra.saddle_point(self.factorize, lambda A: flow_preconditioner(
            self, A, x, rho, params, transpose_tol=self.linear_algebra.adjoint_tol))

    def solve(self, x=None, rho=None, w0=None, params=None) -> tuple[np.ndarray, FlowReport]:
        """Steady flow on the mesh moved by ``x`` with densities ``rho``; raises on failure."""
        solution = self.newton_solve(x, rho, w0, params)
        return solution.w, solution.report

    def newton_solve(self, x=None, rho=None, w0=None, params=None,
                     solver: RecyclingSolver | None = None, tol: float | None = None) -> FlowSolution:
        """:meth:`solve` with the converged Jacobian and the solver (``solver``: one whose last
        factorization may precondition this solve's Newton steps; a new one by default; ``tol``:
        the Newton's tolerance instead of ``fluid.newton_tol``):
        :func:`tofsi.physics.flow_newton.newton_solve`."""
        return newton_solve(self, x, rho, w0, params, solver, tol)

    def residual_scale(self, x, density) -> float:
        """``|F|`` of the all-fluid state holding only the boundary values: the force scale the
        Newton tolerance is relative to (per mesh position and density; independent of the
        design, so a design's solve never depends on which design came first)."""
        def scale():                                           # alpha(None) = alpha_min: q-free
            r = np.linalg.norm(self.bc.homogenize(self.residual(self.initial(), x, None, density)))
            return max(r, 1e-14 * max(1.0, abs(self.settings.inlet_velocity)))
        return self.kept_scale.get(self.evaluation_key(None, x, None, None, density), scale)

    # ---- figures -------------------------------------------------------------------
    def figures(self, w, x=None, rho=None, params=None) -> dict:
        """Pressure drop [Pa] and dissipated power [W/m] of a flow state.

        ``dissipated_power = int 2 mu eps(v) : eps(v) + alpha |v|^2`` is the power the
        flow loses to viscosity and to Brinkman friction (the symmetric strain rate,
        whatever the residual's form).
        """
        view = self.view(w, x, rho, params)
        _, wdet, v, L = view.fields
        eps = 0.5 * (L + np.swapaxes(L, -1, -2))
        alpha = view.coefficients.alpha
        viscous = float(np.sum(2 * self.settings.viscosity * np.einsum("egij,egij->eg", eps, eps) * wdet))
        friction = float(np.sum(alpha[:, None] * np.einsum("egi,egi->eg", v, v) * wdet))
        out = {"dissipated_power": viscous + friction, "viscous_dissipation": viscous,
               "brinkman_dissipation": friction}
        if self.boundary.has_pressure_drop:
            out["pressure_drop"] = float(self.boundary.pressure_drop_weights() @ w[self.n_velocity:])
        return out
