"""The flow ``w = (v, p)``: its settings (``[fluid]``), its block and its :class:`~tofsi.fields.base.Field` entry.

Steady incompressible Navier-Stokes (or Stokes) with Brinkman friction
``alpha(rho) v`` on the (moved) fluid mesh, Taylor-Hood Q2/Q1 or stabilized
equal-order Q1/Q1 (:mod:`tofsi.physics.flow`). The block's residual is ``F``
in the constrained form; its inputs are the mesh motion ``x`` when the scene
is two-way; its linearization is the converged Newton Jacobian and its
recycled LU. Prescribed velocities are constants, so the matrix eliminates
the Dirichlet columns and the partials have zero fixed rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tofsi.core.blocks import FieldBlock
from tofsi.core.config import option
from tofsi.core.errors import InputError
from tofsi.core.registry import FIELDS
from tofsi.fields.base import MOTION_ONLY, EliminatedLinearization, Field, Memory, Picture, moved_mesh, on_q2_nodes
from tofsi.linalg import RecyclingSolver
from tofsi.mesh.structured import DESIGN, SOLID
from tofsi.scene.tables import SceneTable

if TYPE_CHECKING:
    from tofsi.physics.flow import Flow
    from tofsi.physics.fluid_load import FluidForce


# ---- settings: the [fluid] table -------------------------------------------------------------
@dataclass(frozen=True)
class SideFlow:
    """Openings in one side of the channel (table ``[fluid.<side>]``); the rest of the side is a
    no-slip wall. Positions run along the side: y on the left and right sides, x on the bottom
    and top. Listing any opening in any side replaces the default channel (inflow over the
    whole left side, open right side): every side is then a wall except what is listed."""

    inflow: tuple[tuple[float, ...], ...] = option((), length=3,
                                                   doc="prescribed inflow segments [from, to, peak]: "
                                                       "parabolic velocity into the channel [m, m, m/s]")
    outflow: tuple[tuple[float, ...], ...] = option((), length=3,
                                                    doc="prescribed outflow segments [from, to, peak]: "
                                                        "parabolic velocity out of the channel [m, m, m/s]")
    open: tuple[tuple[float, ...], ...] = option((), length=2,
                                                 doc="open outlet segments [from, to] [m] with the natural "
                                                     "condition of fluid.outlet")
    uniform: tuple[tuple[float, ...], ...] = option((), length=4,
                                                    doc="segments [from, to, vx, vy] where the velocity is "
                                                        "the constant (vx, vy), end points included [m, m, "
                                                        "m/s, m/s]: a free stream or a moving wall (topFlow's "
                                                        "rugby ball)")

    def __post_init__(self):
        for name in ("inflow", "outflow", "open", "uniform"):
            for i, segment in enumerate(getattr(self, name)):
                if not segment[0] < segment[1]:
                    raise InputError(f"{name}[{i}]", list(segment[:2]), "need from < to")

    @property
    def is_empty(self) -> bool:
        return not (self.inflow or self.outflow or self.open or self.uniform)


@dataclass(frozen=True)
class FluidSettings:
    """Steady incompressible flow with Brinkman friction (table ``[fluid]``)."""

    density: float = option(1.0, ge=0, doc="fluid density [kg/m^3]; 0 gives Stokes flow")
    viscosity: float = option(1.0, gt=0, doc="dynamic viscosity [Pa s]")
    inlet_velocity: float = option(1.0, doc="peak of the parabolic inflow over the whole left side "
                                                 "(the default channel) [m/s]")
    inlets: tuple[tuple[float, ...], ...] = option((), length=3,
                                                   doc="inflow segments [y0, y1, peak velocity] on "
                                                       "the left side; empty: the whole side (unless "
                                                       "a fluid.<side> table lists openings)")
    outlets: tuple[tuple[float, ...], ...] = option((), length=3,
                                                    doc="prescribed outflow segments [y0, y1, peak] on "
                                                        "the right side; empty: the side open (unless "
                                                        "a fluid.<side> table lists openings)")
    element: str = option("q2q1", choices=("q2q1", "q1q1"),
                          doc="finite element: q2q1, Taylor-Hood (inf-sup stable, exact for Poiseuille "
                              "flow); q1q1, equal-order bilinear velocity and pressure with topFlow's "
                              "SUPG/PSPG stabilization (the element of topFlow and TOFLUX: a third of "
                              "the unknowns on the same mesh, one order less accurate)")
    outlet: str = option("zero-pressure", choices=("zero-pressure", "traction-free", "fixed-pressure"),
                         doc="outlet condition: zero-pressure, mu dv/dn - p n = 0 (zero pressure for "
                             "developed flow); traction-free, (-p I + 2 mu eps(v)) n = 0; "
                             "fixed-pressure, p = 0 at the open segments' nodes, their end nodes "
                             "included (normal velocity free there), with the strain-rate viscous "
                             "form: topFlow's and TOFLUX's outlets")
    parallel_outflow: bool = option(False, doc="open outlets: tangential velocity 0, the flow leaves "
                                               "along the normal (as topFlow's outlets)")
    left: SideFlow = option(SideFlow(), doc="openings in the left side")
    right: SideFlow = option(SideFlow(), doc="openings in the right side")
    bottom: SideFlow = option(SideFlow(), doc="openings in the bottom side")
    top: SideFlow = option(SideFlow(), doc="openings in the top side")
    alpha_max: float = option(1e5, gt=0, le=1e15, doc="Brinkman friction of solid [kg/(m^3 s)] (at most "
                              "1e15: beyond, the solid's rows exceed the viscous ones by more than "
                              "double precision holds)")
    alpha_min: float = option(0.0, ge=0, doc="Brinkman friction of fluid [kg/(m^3 s)]")
    newton_tol: float = option(1e-10, gt=0, lt=1, doc="Newton tolerance on the residual, "
                               "relative to the residual of the zero state")
    newton_max_iter: int = option(25, ge=1, le=1000, doc="Newton iterations per solve")
    continuation_steps: int = option(4, ge=1, le=100,
                                     doc="Reynolds continuation steps tried when a direct "
                                         "Navier-Stokes solve fails")

    def __post_init__(self):
        if self.alpha_min > self.alpha_max:
            raise InputError("alpha_min", self.alpha_min,
                             f"allowed: 0 <= alpha_min <= alpha_max = {self.alpha_max}")
        for name in ("inlets", "outlets"):
            for i, (y0, y1, _) in enumerate(getattr(self, name)):
                if not y0 < y1:
                    raise InputError(f"{name}[{i}]", [y0, y1], "need y0 < y1")



def check_openings(scene) -> None:
    """The left inlets and right outlets lie on the channel's sides."""
    geometry, fluid = scene.geometry, scene.fluid
    for name, side in (("inlets", "left"), ("outlets", "right")):
        for i, (y0, y1, _) in enumerate(getattr(fluid, name)):
            if y0 < 0 or y1 > geometry.height:
                raise InputError(f"fluid.{name}[{i}]", [y0, y1], f"extends outside the channel's "
                                 f"{side} side; need 0 <= y0 < y1 <= geometry.height = {geometry.height:g}")


FLUID_TABLE = SceneTable("fluid", FluidSettings, check=check_openings)


# ---- the block -------------------------------------------------------------------------------
class FlowLinearization(EliminatedLinearization):
    def __init__(self, block, fields, rho, params, jacobian=None, residual=None, solver=None):
        super().__init__(block, fields, rho, params)
        self._J, self._residual, self._solver = jacobian, residual, solver

    @property
    def flow(self) -> Flow:
        return self.block.flow

    @property
    def X(self):
        return moved_mesh(self.fields, self.block.inputs)

    def _linearize(self):
        J, R = self.flow.jacobian(self.value, self.X, self.rho, params=self.params)
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


class FlowBlock(FieldBlock):
    """The flow ``w = (v, p)``: Taylor-Hood Navier-Stokes/Stokes with Brinkman friction."""

    name, symbol, report_name = "w", "F", "flow"
    takes_tolerance = True

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
        return self.constrain(self.flow.residual(w, moved_mesh(fields, self.inputs), rho, params=params), w, params)

    def linearize(self, fields, rho, params):
        return FlowLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None, tol=None):
        X = moved_mesh(fields, self.inputs)
        solution = self.flow.newton_solve(X, rho, guess, params,
                                          solver=None if previous is None else previous.solver, tol=tol)
        values = {**fields, "w": solution.w}
        lin = FlowLinearization(self, values, rho, params, jacobian=solution.jacobian,
                                solver=solution.solver)
        return solution.w, lin, solution.report.as_dict()

    def residual_scale(self, fields, rho, params, lin):
        return self.flow.residual_scale(moved_mesh(fields, self.inputs), self.flow.density)

    def ordering_grid(self):
        return self.flow.grid(), self.flow.pressure_dofs

    def ordering(self):
        return self.flow.ordering


# ---- the registry entry ----------------------------------------------------------------------
class FlowEntry(Field):
    """``w``: Navier-Stokes or Stokes flow with Brinkman friction (Taylor-Hood, or stabilized
    equal order with ``fluid.element = "q1q1"``)."""

    name, title, tables = "w", "flow", (FLUID_TABLE,)
    summary = ("pressure_drop", "dissipated_power", "drag", "lift")
    picture_names = ("velocity", "pressure")

    def active(self, scene, command="solve"):
        return scene.effects.fluid != "none" and command not in MOTION_ONLY

    def memory(self, grid, scene):
        from tofsi.physics.fluid_elements import ELEMENTS
        element = ELEMENTS[scene.fluid.element]     # 1e3 bytes per element with the kernel in chunks (fitted;
        return Memory(element.unknowns(grid), element.fill, 1.0e3)   # q1q1 peaks at 4005 and 22 578 elements:
                                                                     # 182 and 670 MB, estimated 1.34x, 1.04x)

    def build(self, model):
        from tofsi.physics.flow import Flow
        return Flow(model.mesh, model.scene.fluid, stokes=model.scene.effects.fluid == "stokes",
                    linear_algebra=model.linear_algebra,
                    keep_element_jacobians=model.scene.effects.coupling == "two-way")

    def block(self, model, stage):
        return FlowBlock(model.flow, moving_mesh=stage.coupling == "two-way")

    def figures(self, model, state):
        """Pressure drop, dissipation and, where there is a solid, drag and lift: the resultant
        of the fluid load on the solid phase [N/m]."""
        if state.w is None:
            return {}
        X = state.mesh_displacement
        out = model.flow.figures(state.w, X, state.rho, state.params)
        if model.force is not None:
            out["drag"], out["lift"] = model.force.resultant(state.w, X, state.rho, state.params)
        return out

    def point_data(self, model, state):
        if state.w is None:
            return {}
        flow = model.flow
        v = state.w[:flow.n_velocity].reshape(-1, 2)
        return {"velocity": on_q2_nodes(model.mesh, v) if flow.element.velocity_on_corners else v,
                "pressure": on_q2_nodes(model.mesh, state.w[flow.n_velocity:])}

    def pictures(self, model, state):
        if state.w is None:
            return []
        speed = np.linalg.norm(model.flow.corner_velocity(state.w), axis=1)
        return [Picture("velocity", "velocity magnitude", "|v| [m/s]", speed),
                Picture("pressure", "pressure", "p [Pa]", state.w[model.flow.n_velocity:], cmap="coolwarm")]


FIELDS.register(FlowEntry())


def has_solid(mesh) -> bool:
    """Whether a mesh has fixed solid or design elements (that the flow exerts a force on)."""
    return bool(np.isin(mesh.region, (SOLID, DESIGN)).any())


def fluid_force(model) -> FluidForce | None:
    """The fluid's force on the solid phase: the structure's load where there is a structure,
    else a load of the scene's form for the drag and lift figures (None without flow or solid)."""
    if model.structure is not None:
        return model.structure.force
    if model.flow is None or not has_solid(model.mesh):
        return None
    from tofsi.physics.fluid_load import FluidForce
    return FluidForce(model.flow, model.scene.structure.load)
