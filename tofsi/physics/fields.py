"""The physics as field blocks (:mod:`tofsi.blocks`): flow ``w``, structure ``u``, mesh motion ``x``.

Each block adapts a physics object to the protocol -- its residual in the
constrained form, its solve, and a linearization that owns the
factorization of its own Jacobian:

===========  =========  ==================  ==========================================================
field        residual   inputs              linearization
===========  =========  ==================  ==========================================================
``w`` flow   ``F``      ``x`` if two-way    converged Newton Jacobian, recycled LU
``u``        ``S``      ``w`` (and ``x``)   LU of ``K_s(rho)`` (finite strain: the tangent, recycled)
``x`` mesh   ``D``      ``u``               mover tangent (or the mover's VJP)
===========  =========  ==================  ==========================================================

Prescribed values of the flow and the structure are constants, so their
matrices eliminate the Dirichlet columns and their partials have zero fixed
rows; the mesh's prescribed values follow the structure, so its Jacobian
keeps them (see :meth:`movers.base.Mover.residual`).
"""

from __future__ import annotations

import numpy as np

from tofsi.blocks import ExplicitLinearization, FieldBlock, Linearization
from tofsi.linalg import AMGSolver, RecyclingSolver, rigid_body_modes
from tofsi.physics.flow import Flow
from tofsi.physics.mesh_motion import MeshMotion
from tofsi.physics.structure import Structure


def _moved(fields, inputs) -> np.ndarray | None:
    """The mesh displacement ``(n, 2)`` a block sees (None: the reference mesh)."""
    x = fields.get("x") if "x" in inputs else None
    return None if x is None else np.asarray(x).reshape(-1, 2)


class _EliminatedLinearization(Linearization):
    """Shared by blocks with constant prescribed values: ``matrix()`` eliminates the Dirichlet
    columns, the partials have zero fixed rows, so ``lam`` counts on the free dofs only."""

    def solve(self, b):
        z = self.factor_solve(self.block.homogenize(b))
        z[self.block.fixed] = np.asarray(b)[self.block.fixed]
        return z

    def solve_transpose(self, b):
        z = self.factor_solve_transpose(self.block.homogenize(b))
        z[self.block.fixed] = np.asarray(b)[self.block.fixed]
        return z


# ---- flow ---------------------------------------------------------------------------------
class FlowLinearization(_EliminatedLinearization):
    def __init__(self, block, fields, rho, params, jacobian=None, residual=None, solver=None):
        super().__init__(block, fields, rho, params)
        self._J, self._residual, self._solver = jacobian, residual, solver

    @property
    def flow(self) -> Flow:
        return self.block.flow

    @property
    def X(self):
        return _moved(self.fields, self.block.inputs)

    def _linearize(self):
        J, R, _ = self.flow.jacobian(self.value, self.X, self.rho, params=self.params)
        self._J = J
        if self._residual is None:
            self._residual = self.block.constrain(R, self.value, self.params)

    def matrix(self):
        if self._J is None:
            self._linearize()
        return self._J

    @property
    def residual(self):
        if self._residual is None:
            self._linearize()
        return self._residual

    def _solver_for(self):
        if self._solver is None:
            self._solver = RecyclingSolver(self.flow.factorizer(self.X, self.rho, self.params))
        return self._solver

    @property
    def solver(self):
        """The recycling solver holding the last factorization (reused by a later solve)."""
        return self._solver

    def factor_solve(self, b):
        return self._solver_for().solve(self.matrix(), b)

    def factor_solve_transpose(self, b):
        return self._solver_for().solve_transpose(self.matrix(), b)

    def coupling(self, other):
        if other != "x":
            return None
        fl = self.flow
        return self.kept("F_x", lambda: fl.bc.free_rows(fl.shape_partial(self.value, self.X, self.rho,
                                                                          self.params)))

    def density(self):
        fl = self.flow
        return self.kept("F_rho", lambda: fl.bc.free_rows(fl.density_partial(self.value, self.X, self.rho,
                                                                              self.params)))

    def transpose_partials(self, lam):
        lam = self.block.homogenize(lam)
        fl = self.flow
        bars = {}
        if "x" in self.block.inputs:
            bars["x"] = self.coupling("x").T @ lam
        rho_bar = np.einsum("ea,ea->e", fl.density_vectors(self.value, self.X, self.rho, self.params),
                            lam[fl.dofs])
        return bars, rho_bar


class FlowField(FieldBlock):
    """The flow ``w = (v, p)``: Taylor-Hood Navier-Stokes/Stokes with Brinkman friction."""

    name, symbol, report_name = "w", "F", "flow"

    def __init__(self, flow: Flow, moving_mesh: bool = False):
        self.flow = flow
        self.size = flow.size
        self.inputs = ("x",) if moving_mesh else ()
        self.slow_couplings = self.inputs            # F_x: the shape derivative

    @property
    def fixed(self):
        return self.flow.bc.fixed

    def constrain(self, R, w, params):
        """The constrained residual: free rows ``F``, fixed rows ``w - g`` (``g`` at the load of
        ``params``)."""
        r = self.flow.bc.homogenize(R)
        r[self.fixed] = (w - self.flow.boundary_values(params))[self.fixed]
        return r

    def initial(self, fields, rho, params):
        return self.flow.initial(params)

    def residual(self, fields, rho, params):
        w = fields["w"]
        return self.constrain(self.flow.residual(w, _moved(fields, self.inputs), rho, params=params), w, params)

    def linearize(self, fields, rho, params):
        return FlowLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None):
        X = _moved(fields, self.inputs)
        solution = self.flow.newton_solve(X, rho, guess, params,
                                          solver=None if previous is None else previous.solver)
        values = {**fields, "w": solution.w}
        lin = FlowLinearization(self, values, rho, params, jacobian=solution.jacobian,
                                solver=solution.solver)
        return solution.w, lin, solution.report.as_dict()

    def residual_scale(self, fields, rho, params, lin):
        return self.flow.residual_scale(_moved(fields, self.inputs), self.flow.density)

    def ordering_grid(self):
        return self.flow.grid(), self.flow.pressure_dofs


# ---- structure ---------------------------------------------------------------------------
class StructureLinearization(_EliminatedLinearization):
    """Small strain: ``S_u = K_s(rho)`` and its LU. Finite strain: ``S_u`` the tangent at ``u``,
    solved by the Newton's recycling solver (its last factorization preconditions GMRES)."""

    def __init__(self, block, fields, rho, params, factor=None, solver=None):
        super().__init__(block, fields, rho, params)
        self._factor = factor
        self._solver = solver
        self._residual = None

    @property
    def st(self) -> Structure:
        return self.block.structure

    @property
    def X(self):
        return _moved(self.fields, self.block.inputs)

    @property
    def residual(self):
        if self._residual is None:
            self._residual = self.block.residual(self.fields, self.rho, self.params)
        return self._residual

    def matrix(self):
        if self.st.nonlinear(self.params):
            return self.kept("S_u", lambda: self.st.stiffness(self.rho, self.params, self.value))
        return self.st.stiffness(self.rho, self.params)

    def factorization(self):
        """The LU of ``K_s(rho)`` at this point's SIMP exponent (small strain)."""
        if self._factor is None:
            self._factor = self.st.factorize(self.rho, self.params)
        return self._factor

    @property
    def solver(self):
        """Finite strain: the recycling solver of the tangent (None before first use)."""
        return self._solver

    def _solver_for(self):
        if self._solver is None:
            self._solver = RecyclingSolver(self.st.direct)
        return self._solver

    def factor_solve(self, b):
        if self.st.nonlinear(self.params):
            return self._solver_for().solve(self.matrix(), b)
        return self.factorization().solve(b)

    def factor_solve_transpose(self, b):
        if self.st.nonlinear(self.params):
            return self._solver_for().solve_transpose(self.matrix(), b)
        return self.factorization().solve_transpose(b)

    def coupling(self, other):
        st, w = self.st, self.fields.get("w")
        if other == "w" and "w" in self.block.inputs:
            return self.kept("S_w", lambda: st.bc.free_rows(st.fluid_partial(w, self.X, self.rho, self.params)))
        if other == "x" and "x" in self.block.inputs:
            return self.kept("S_x", lambda: st.bc.free_rows(st.shape_partial(w, self.X, self.rho, self.params)))
        return None

    def density(self):
        return self.kept("S_rho", lambda: self.st.bc.free_rows(
            self.st.density_partial(self.value, self.fields.get("w"), self.X, self.rho, self.params)))

    def transpose_partials(self, lam):
        lam = self.block.homogenize(lam)
        st, w = self.st, self.fields.get("w")
        bars = {}
        if "w" in self.block.inputs:
            bars["w"] = st.fluid_partial_transpose(lam, w, self.X, self.rho, self.params)
        if "x" in self.block.inputs:
            bars["x"] = self.coupling("x").T @ lam
        rho_bar = np.einsum("ea,ea->e", st.density_vectors(self.value, w, self.X, self.rho, self.params),
                            lam[st.dofs])
        return bars, rho_bar


class StructureField(FieldBlock):
    """The structure's displacement ``u``: SIMP plane-strain elasticity loaded by the flow and
    its weight, or by its weight alone (no flow: no input); at finite strain solved by Newton,
    whose report is the state's ``structure`` report."""

    name, symbol, report_name = "u", "S", ""

    def __init__(self, structure: Structure, moving_mesh: bool = False):
        self.structure = structure
        self.report_name = "structure"          # a finite-strain solve's Newton report (small strain: none)
        self.size = structure.size
        self.inputs = (("w",) if structure.force is not None else ()) + (("x",) if moving_mesh else ())
        self.slow_couplings = ("x",) if moving_mesh else ()     # S_x: the load's shape derivative

    @property
    def fixed(self):
        return self.structure.bc.fixed

    def initial(self, fields, rho, params):
        return np.zeros(self.size)

    def residual(self, fields, rho, params):
        st, u = self.structure, fields["u"]
        r = st.bc.homogenize(st.residual(u, fields.get("w"), _moved(fields, self.inputs), rho, params))
        r[self.fixed] = u[self.fixed]
        return r

    def linearize(self, fields, rho, params):
        return StructureLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None):
        if self.structure.nonlinear(params):  # Newton from the guess (a nearby state), else load steps
            recycled = previous.solver if isinstance(previous, StructureLinearization) else None
            solution = self.structure.newton_solve(fields.get("w"), _moved(fields, self.inputs), rho, params,
                                                   guess=guess, solver=recycled)
            lin = StructureLinearization(self, {**fields, "u": solution.u}, rho, params, solver=solution.solver)
            return solution.u, lin, solution.report.as_dict()
        factor = None
        if (previous is not None and np.array_equal(previous.rho, rho) and previous.params.penalty == params.penalty
                and not self.structure.nonlinear(previous.params)):
            factor = previous.factorization()                     # K_s depends on (rho, p) only
        values = dict(fields)
        lin = StructureLinearization(self, values, rho, params, factor)
        u = self.structure.solve(fields.get("w"), _moved(fields, self.inputs), rho, params, lin.factorization())
        lin.fields["u"] = u
        return u, lin, None

    def residual_scale(self, fields, rho, params, lin):
        load = self.structure.load(fields.get("w"), _moved(fields, self.inputs), rho, params)
        return max(float(np.linalg.norm(load)), 1e-300)

    def ordering_grid(self):
        return self.structure.grid, np.zeros(self.size, dtype=bool)


# ---- mesh motion -------------------------------------------------------------------------
class MotionLinearization(Linearization):
    """A residual mover's derivatives: ``D_x`` (true Jacobian), ``D_u``, ``D_rho``."""

    def __init__(self, block, fields, rho, params, solver=None):
        super().__init__(block, fields, rho, params)
        self._solver = solver
        self._rD = None

    @property
    def motion(self) -> MeshMotion:
        return self.block.motion

    def _at(self):
        if self._rD is None:
            self._rD = self.motion.residual(self.value, self.fields["u"], self.rho)
        return self._rD

    @property
    def residual(self):
        return self._at()[0]

    def matrix(self):
        return self._at()[1]

    @property
    def solver(self):
        """The forward move's solver (None if there is none yet), recycled by the next move."""
        return self._solver

    def _solver_for(self):
        if self._solver is None:
            motion = self.motion
            if motion.linear_algebra.iterative:           # AMG-GMRES (the blended tangent is not symmetric)
                modes = rigid_body_modes(motion.base.points)
                self._solver = RecyclingSolver(lambda A: AMGSolver(A, near_null=modes, symmetric=False))
            else:
                self._solver = RecyclingSolver(lambda A: motion.linear_algebra.direct(A, perm=motion.base.ordering))
        return self._solver

    def solve(self, b):
        return self._solver_for().solve(self.matrix(), b)

    def solve_transpose(self, b):
        return self.motion.transposed_solve(self.value, self.rho, b, self._solver)

    def coupling(self, other):
        return self.kept("D_u", lambda: self.motion.structure_partial(self.rho)) if other == "u" else None

    def transpose_partials(self, lam):
        u_bar, rho_bar = self.motion.partials_transpose(self.value, self.fields["u"], self.rho, lam)
        return {"u": u_bar}, rho_bar


class MotionField(FieldBlock):
    """The fluid-mesh displacement ``x``: the scene's mover driven by the structure."""

    name, symbol, report_name = "x", "D", "mover"
    inputs = ("u",)

    def __init__(self, motion: MeshMotion):
        self.motion = motion
        self.size = 2 * motion.mesh.n_nodes
        self.has_residual = not motion.path_dependent

    @property
    def fixed(self):
        return self.motion.fixed_dofs

    def initial(self, fields, rho, params):
        return np.zeros(self.size)

    def residual(self, fields, rho, params):
        if self.has_residual:
            return self.motion.residual(fields["x"], fields["u"], rho, jacobian=False)[0]
        return fields["x"] - self.motion.move(fields["u"], rho).displacement.ravel()

    def linearize(self, fields, rho, params):
        if not self.has_residual:
            raise NotImplementedError("a path-dependent mover has no residual to linearize")
        return MotionLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None):
        recycled = previous.solver if isinstance(previous, MotionLinearization) else None
        result = self.motion.move(fields["u"], rho, progress, initial=guess, solver=recycled)   # warm starts
        x = result.displacement.ravel()
        values = {**fields, "x": x}
        if self.has_residual:
            lin = MotionLinearization(self, values, rho, params, solver=result.solver)
        else:
            def vjp(x_bar):
                u_bar, rho_bar = self.motion.vjp(result, x_bar.reshape(-1, 2), rho)
                return {"u": u_bar}, rho_bar
            lin = ExplicitLinearization(self, values, rho, params, vjp)
        return x, lin, result.report.as_dict()

    def residual_scale(self, fields, rho, params, lin):
        x = fields["x"]
        return max(float(np.linalg.norm(lin.residual)), float(np.linalg.norm(lin.matrix() @ x)), 1e-300)

    def ordering_grid(self):
        return np.repeat(self.motion.mesh.grid_positions(), 2, axis=0), np.zeros(self.size, dtype=bool)

