"""The structure ``u``: its settings (``[structure]``), its block and its :class:`~tofsi.fields.base.Field` entry.

Plane-strain elasticity with SIMP, small strain or neo-Hookean finite strain,
loaded by the fluid (:mod:`tofsi.physics.structure`). The block's residual is
``S``, its inputs the flow ``w`` (and the mesh motion ``x`` when two-way); its
linearization is the LU of ``K_s(rho)`` at small strain, the tangent and the
Newton's recycled solver at finite strain. Prescribed displacements are
constants, so the matrix eliminates the Dirichlet columns.
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
from tofsi.mesh.structured import SIDES
from tofsi.scene.tables import SceneTable

if TYPE_CHECKING:
    from tofsi.physics.structure import Structure


# ---- settings: the [structure] table ---------------------------------------------------------
@dataclass(frozen=True)
class StructureSettings:
    """Plane-strain elasticity with SIMP interpolation, small or finite strain (table ``[structure]``)."""

    youngs_modulus: float = option(1e5, gt=0, doc="Young's modulus of solid E0 [Pa]")
    poisson_ratio: float = option(0.3, gt=-1.0, lt=0.5, doc="Poisson's ratio")
    e_min_ratio: float = option(1e-9, gt=0, lt=1, doc="Emin / E0 of void (fluid) elements")
    clamped: tuple[str, ...] = option(("bottom",), choices=SIDES,
                                      doc="channel sides where the structure is clamped (at least one)")
    load: str = option("reaction", choices=("reaction", "stress-divergence", "pressure"),
                       doc="the fluid's force on the solid: reaction, the momentum-consistent "
                           "reaction of the fluid residual (its resultant tends to the no-slip "
                           "body's drag and lift); stress-divergence, Lundgaard et al. 2018's "
                           "volume form of the total stress inside the solid (loses the viscous "
                           "shear of an unresolved Brinkman layer; for reproducing published results); "
                           "pressure, the same form with the pressure alone (TOFLUX's load)")
    load_exponent: float = option(1.0, ge=1, le=10,
                                  doc="weight rho^k of the solid phase in the fluid load (1: Lundgaard "
                                      "et al.; the SIMP exponent keeps gray elements' displacement "
                                      "bounded)")
    model: str = option("linear", choices=("linear", "neo-hookean"),
                        doc="linear: small-strain elasticity; neo-hookean: compressible neo-Hookean at "
                            "finite strain (plane strain, total Lagrangian), solved by Newton with load "
                            "steps; the fluid load acts on the moved configuration")
    interpolation: str = option("energy", choices=("energy", "simp"),
                                doc="neo-hookean: nearly void elements -- energy: Wang et al. 2014's "
                                    "blend of the nonlinear and the linear strain energy by density "
                                    "(void elements linear, so they cannot invert or stall Newton); "
                                    "simp: every element neo-Hookean")
    energy_threshold: float = option(0.01, gt=0, lt=1,
                                     doc="neo-hookean, energy: density rho0 where the blend g(rho) turns "
                                         "from linear (below) to nonlinear (above)")
    energy_sharpness: float = option(500.0, gt=0, le=1e4, doc="neo-hookean, energy: steepness beta of g(rho)")
    newton_tol: float = option(1e-10, gt=0, lt=1, doc="neo-hookean: Newton tolerance, the norm of S on "
                                                      "the free dofs relative to the load's")
    max_newton: int = option(25, ge=1, le=1000, doc="neo-hookean: Newton iterations per load step")
    max_cutbacks: int = option(20, ge=0, le=1000, doc="neo-hookean: halvings of the load step before failing")

    def __post_init__(self):
        if not self.clamped:
            raise InputError("clamped", [], "allowed: at least one of " + ", ".join(map(repr, SIDES))
                             + " (a structure held nowhere has no stiffness against rigid motion)")



STRUCTURE_TABLE = SceneTable("structure", StructureSettings)


# ---- the block -------------------------------------------------------------------------------
class StructureLinearization(EliminatedLinearization):
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
        return moved_mesh(self.fields, self.block.inputs)

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
        st, w = self.st, self.fields["w"]
        if other == "w":
            return self.kept("S_w", lambda: st.bc.free_rows(st.fluid_partial(w, self.X, self.rho, self.params)))
        if other == "x" and "x" in self.block.inputs:
            return self.kept("S_x", lambda: st.bc.free_rows(st.shape_partial(w, self.X, self.rho, self.params)))
        return None

    def density(self):
        return self.kept("S_rho", lambda: self.st.bc.free_rows(
            self.st.density_partial(self.value, self.fields["w"], self.X, self.rho, self.params)))

    def transpose_partials(self, lam):
        lam = self.block.homogenize(lam)
        st, w = self.st, self.fields["w"]
        bars = {"w": st.fluid_partial_transpose(lam, w, self.X, self.rho, self.params)}
        if "x" in self.block.inputs:
            bars["x"] = self.coupling("x").T @ lam
        rho_bar = np.einsum("ea,ea->e", st.density_vectors(self.value, w, self.X, self.rho, self.params),
                            lam[st.dofs])
        return bars, rho_bar


class StructureBlock(FieldBlock):
    """The structure's displacement ``u``: SIMP plane-strain elasticity loaded by the flow
    (at finite strain solved by Newton, whose report is the state's ``structure`` report)."""

    name, symbol, report_name = "u", "S", ""

    def __init__(self, structure: Structure, moving_mesh: bool = False):
        self.structure = structure
        self.report_name = "structure"          # a finite-strain solve's Newton report (small strain: none)
        self.size = structure.size
        self.inputs = ("w", "x") if moving_mesh else ("w",)
        self.slow_couplings = ("x",) if moving_mesh else ()     # S_x: the load's shape derivative

    @property
    def fixed(self):
        return self.structure.bc.fixed

    def initial(self, fields, rho, params):
        return np.zeros(self.size)

    def residual(self, fields, rho, params):
        st, u = self.structure, fields["u"]
        r = st.bc.homogenize(st.residual(u, fields["w"], moved_mesh(fields, self.inputs), rho, params))
        r[self.fixed] = u[self.fixed]
        return r

    def linearize(self, fields, rho, params):
        return StructureLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None):
        if self.structure.nonlinear(params):  # Newton from the guess (a nearby state), else load steps
            recycled = previous.solver if isinstance(previous, StructureLinearization) else None
            solution = self.structure.newton_solve(fields["w"], moved_mesh(fields, self.inputs), rho, params,
                                                   guess=guess, solver=recycled)
            lin = StructureLinearization(self, {**fields, "u": solution.u}, rho, params, solver=solution.solver)
            return solution.u, lin, solution.report.as_dict()
        factor = None
        if (previous is not None and np.array_equal(previous.rho, rho) and previous.params.penalty == params.penalty
                and not self.structure.nonlinear(previous.params)):
            factor = previous.factorization()                     # K_s depends on (rho, p) only
        values = dict(fields)
        lin = StructureLinearization(self, values, rho, params, factor)
        u = self.structure.solve(fields["w"], moved_mesh(fields, self.inputs), rho, params, lin.factorization())
        lin.fields["u"] = u
        return u, lin, None

    def residual_scale(self, fields, rho, params, lin):
        load = self.structure.load(fields["w"], moved_mesh(fields, self.inputs), rho, params)
        return max(float(np.linalg.norm(load)), 1e-300)

    def ordering_grid(self):
        return self.structure.grid, np.zeros(self.size, dtype=bool)


# ---- the registry entry ----------------------------------------------------------------------
class StructureEntry(Field):
    """``u``: plane-strain elasticity with SIMP, loaded by the flow."""

    name, title, tables = "u", "structure", (STRUCTURE_TABLE,)
    summary = ("compliance", "max_displacement", "max_solid_displacement")
    picture_names = ("deformed",)

    def active(self, scene, command="solve"):
        return scene.effects.structure != "none" and command not in MOTION_ONLY

    def memory(self, grid, scene):
        return Memory(2 * grid.nodes, "q1-vector", 1.0e3)

    def build(self, model):
        if model.flow is None:
            raise InputError("effects.structure", model.scene.effects.structure,
                             "the structure is loaded by the flow; set effects.fluid too")
        from tofsi.physics.structure import Structure
        return Structure(model.mesh, model.scene.structure, model.flow, linear_algebra=model.linear_algebra)

    def block(self, model, two_way):
        return StructureBlock(model.structure, moving_mesh=two_way)

    def check(self, model, state):
        """A displacement beyond the channel: one-way, an answer but no physical state (a design
        far too soft for the flow); where the mesh moved with it (two-way), a failure."""
        if state.u is None:
            return []
        structure = model.structure
        if state.x is not None:
            structure.check_displacement(state.u)
            return []
        beyond = structure.displacement_beyond_channel(state.u)
        if not beyond:
            return []
        strain = "finite-strain" if structure.nonlinear(state.params) else "small-strain"
        return [beyond + f": the {strain} answer for a design far too soft for the flow, not a physical "
                "state (optimize starts from it)"]

    def figures(self, model, state):
        if state.u is None:
            return {}
        return model.structure.figures(state.u, state.w, state.mesh_displacement, state.rho, state.params)

    def point_data(self, model, state):
        if state.u is None:
            return {}
        return {"structure_displacement": on_q2_nodes(model.mesh, state.u.reshape(-1, 2))}

    def pictures(self, model, state):
        """The structure on its displaced nodes, magnified to a tenth of the channel where the
        motion is small (at most 1 where the mesh moved with it)."""
        if state.u is None:
            return []
        mesh = model.mesh
        U = state.u.reshape(-1, 2)
        scale = 0.1 * np.ptp(mesh.points, axis=0).max() / max(np.abs(U).max(), 1e-300)
        scale = min(scale, 1.0) if state.x is not None else scale
        size = f"magnified {scale:.3g} times" if scale >= 1 else f"drawn at {scale:.3g} of its size"
        return [Picture("deformed", f"structure displacement ({size})",
                        "density rho (0 fluid, 1 solid)", state.rho, kind="mesh", cmap="Greys",
                        points=mesh.points + scale * U, vmin=0.0, vmax=1.0)]


FIELDS.register(StructureEntry())
