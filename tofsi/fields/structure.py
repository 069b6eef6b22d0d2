"""The structure ``u``: its settings (``[structure]``), its block and its :class:`~tofsi.fields.base.Field` entry.

Plane-strain elasticity with SIMP, small strain or finite strain (neo-Hookean,
Saint Venant-Kirchhoff), loaded by the fluid and the solid's weight
(:mod:`tofsi.physics.structure`). The block's residual is ``S``, its inputs the
flow ``w`` (none when its weight alone loads it; and the mesh motion ``x`` when two-way); its
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
from tofsi.core.registry import FIELDS, MATERIALS
from tofsi.fields.base import MOTION_ONLY, EliminatedLinearization, Field, Memory, Picture, moved_mesh, on_q2_nodes
from tofsi.mesh.channel import named_solids
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
    clamped: tuple[str, ...] = option(("bottom",), doc="where the structure is clamped (at least one): channel "
                                                       "sides (left, right, bottom, top) and named solids "
                                                       "(geometry.solid_names, geometry.circle_names), whose "
                                                       "every node is held")
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
    density: float = option(0.0, ge=0, doc="density of the solid rho_s [kg/m^3]: with structure.gravity its "
                            "weight, a dead load on the solid phase weighted like the fluid load (rho^k)")
    gravity: tuple[float, ...] = option((0.0, 0.0), length=2,
                                        doc="gravitational acceleration [gx, gy] [m/s^2] acting on the solid "
                                            "(e.g. [0, -9.81]); [0, 0]: no weight")
    model: str = option("linear", choices=MATERIALS,
                        doc="the material, an entry of the materials registry (tofsi.physics.materials) -- "
                            "linear: small-strain elasticity; neo-hookean: compressible neo-Hookean at "
                            "finite strain (plane strain, total Lagrangian), solved by Newton with load "
                            "steps; saint-venant-kirchhoff: the same with W = lam/2 (tr E)^2 + mu E:E in "
                            "the Green-Lagrange strain E (Turek & Hron's solid); at finite strain the "
                            "fluid load acts on the moved configuration")
    interpolation: str = option("energy", choices=("energy", "simp"),
                                doc="finite strain: nearly void elements -- energy: Wang et al. 2014's "
                                    "blend of the nonlinear and the linear strain energy by density "
                                    "(void elements linear, so they cannot invert or stall Newton); "
                                    "simp: every element neo-Hookean")
    energy_threshold: float = option(0.01, gt=0, lt=1,
                                     doc="finite strain, energy: density rho0 where the blend g(rho) turns "
                                         "from linear (below) to nonlinear (above)")
    energy_sharpness: float = option(500.0, gt=0, le=1e4, doc="finite strain, energy: steepness beta of g(rho)")
    newton_tol: float = option(1e-10, gt=0, lt=1, doc="finite strain: Newton tolerance, the norm of S on "
                                                      "the free dofs relative to the load's")
    max_newton: int = option(25, ge=1, le=1000, doc="finite strain: Newton iterations per load step")
    max_cutbacks: int = option(20, ge=0, le=1000, doc="finite strain: halvings of the load step before failing")

    def __post_init__(self):
        if not self.clamped:
            raise InputError("clamped", [], "allowed: at least one of " + ", ".join(map(repr, SIDES))
                             + " (a structure held nowhere has no stiffness against rigid motion)")



def check_clamped(scene) -> None:
    """``structure.clamped`` names channel sides and named solids only."""
    geometry = scene.geometry
    names = set(geometry.solid_names) | set(geometry.circle_names)
    for i, name in enumerate(scene.structure.clamped):
        if name not in SIDES and name not in names:
            raise InputError(f"structure.clamped[{i}]", name, "allowed: a channel side (" + ", ".join(SIDES)
                             + ") or a named solid (" + (", ".join(sorted(names)) or "none named: "
                             "geometry.solid_names, geometry.circle_names") + ")")


STRUCTURE_TABLE = SceneTable("structure", StructureSettings, check=check_clamped)


# ---- the block -------------------------------------------------------------------------------
class StructureLinearization(EliminatedLinearization):
    """``S_u``, the tangent of the block's material at ``u`` (small strain: ``K_s(rho)``), solved
    by the material's solver: the LU of ``K_s`` (reused by later sweeps at the same densities), or
    at finite strain the Newton's recycling solver (its last factorization preconditions GMRES)."""

    def __init__(self, block, fields, rho, params, solver=None):
        super().__init__(block, fields, rho, params)
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
        return self.kept("S_u", lambda: self.st.stiffness(self.rho, self.params, self.value, self.block.material))

    @property
    def solver(self):
        """The material's solver of this point's tangent (made on first use)."""
        if self._solver is None:
            self._solver = self.block.material.solver(self.rho, self.st.simp(self.params))
        return self._solver

    def factor_solve(self, b):
        return self.solver.solve(self.matrix, b)

    def factor_solve_transpose(self, b):
        return self.solver.solve_transpose(self.matrix, b)

    def coupling(self, other):
        st, w = self.st, self.fields.get("w")
        if other == "w" and "w" in self.block.inputs:
            return self.kept("S_w", lambda: st.bc.free_rows(st.fluid_partial(w, self.X, self.rho, self.params)))
        if other == "x" and "x" in self.block.inputs:
            return self.kept("S_x", lambda: st.bc.free_rows(st.shape_partial(w, self.X, self.rho, self.params)))
        return None

    def density(self):
        return self.kept("S_rho", lambda: self.st.bc.free_rows(self.st.density_partial(
            self.value, self.fields.get("w"), self.X, self.rho, self.params, self.block.material)))

    def transpose_partials(self, lam):
        lam = self.block.homogenize(lam)
        st, w = self.st, self.fields.get("w")
        bars = {}
        if "w" in self.block.inputs:
            bars["w"] = st.fluid_partial_transpose(lam, w, self.X, self.rho, self.params)
        if "x" in self.block.inputs:
            bars["x"] = self.coupling("x").T @ lam
        vectors = st.density_vectors(self.value, w, self.X, self.rho, self.params, self.block.material)
        return bars, np.einsum("ea,ea->e", vectors, lam[st.dofs])


class StructureBlock(FieldBlock):
    """The structure's displacement ``u`` of one material: SIMP plane-strain elasticity loaded by
    the flow and its weight, or by its weight alone (no flow: no input); a nonlinear material
    solved by Newton, whose report is the state's ``structure`` report."""

    name, symbol, report_name = "u", "S", "structure"
    own_continuation = True            # a nonlinear material's load steps (``direct``: none)
    takes_tolerance = True             # a nonlinear material's Newton (``tol``)

    def __init__(self, structure: Structure, material, moving_mesh: bool = False):
        self.structure, self.material = structure, material
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
        r = st.bc.homogenize(st.residual(u, fields.get("w"), moved_mesh(fields, self.inputs), rho, params,
                                         self.material))
        r[self.fixed] = u[self.fixed]
        return r

    def linearize(self, fields, rho, params):
        return StructureLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None, direct=False, tol=None):
        """From the guess (a nearby state) where the material is nonlinear (``direct``: Newton
        alone, no load steps); the solver of an earlier sweep (``previous``) where it still
        serves (the LU of the same ``K_s``, or the Newton's recycled factorization)."""
        st, simp = self.structure, self.structure.simp(params)
        earlier = previous.solver if isinstance(previous, StructureLinearization) else None
        solver = self.material.solver(rho, simp, earlier)
        load = st.load(fields.get("w"), moved_mesh(fields, self.inputs), rho, params)
        u, report = self.material.solve(load, rho, simp, guess=guess, solver=solver, direct=direct,
                                        **({} if tol is None else {"tol": tol}))
        return u, StructureLinearization(self, {**fields, "u": u}, rho, params, solver), report

    def residual_scale(self, fields, rho, params, lin):
        load = self.structure.load(fields.get("w"), moved_mesh(fields, self.inputs), rho, params)
        return max(float(np.linalg.norm(load)), 1e-300)

    def ordering_grid(self):
        return self.structure.grid, np.zeros(self.size, dtype=bool)

    def ordering(self):
        return self.structure.perm


# ---- the registry entry ----------------------------------------------------------------------
class StructureEntry(Field):
    """``u``: plane-strain elasticity with SIMP, loaded by the flow and the solid's weight."""

    name, title, tables = "u", "structure", (STRUCTURE_TABLE,)
    summary = ("compliance", "max_displacement", "max_solid_displacement")
    picture_names = ("deformed",)

    def active(self, scene, command="solve"):
        return scene.effects.structure != "none" and command not in MOTION_ONLY

    def memory(self, grid, scene):
        return Memory(2 * grid.nodes, "q1-vector", 1.0e3)

    def build(self, model):
        st = model.scene.structure
        if model.flow is None and not (st.density > 0 and any(st.gravity)):
            raise InputError("effects.structure", model.scene.effects.structure,
                             "the structure is loaded by the flow or by its weight; set effects.fluid, "
                             "or structure.density and structure.gravity")
        from tofsi.physics.structure import Structure
        return Structure(model.mesh, st, model.flow, linear_algebra=model.linear_algebra,
                         solids=named_solids(model.scene.geometry, model.mesh))

    def block(self, model, stage):
        structure = model.structure
        return StructureBlock(structure, structure.material(stage.material), moving_mesh=stage.coupling == "two-way")

    def check(self, model, state):
        """A displacement beyond the channel (in either direction, or the solid out of it): one-way,
        an answer but no physical state (a design far too soft for the flow); where the mesh moved
        with it (two-way), a failure."""
        if state.u is None:
            return []
        structure = model.structure
        if state.x is not None:
            structure.check_displacement(state.u, state.rho)
            return []
        beyond = structure.displacement_beyond_channel(state.u, state.rho)
        if not beyond:
            return []
        strain = "finite-strain" if structure.material(state.stage.material).nonlinear else "small-strain"
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
