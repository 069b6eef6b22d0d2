"""The fluid mesh's motion ``x``: its settings (``[mover]``), its block and its :class:`~tofsi.fields.base.Field` entry.

The scene's mover (package :mod:`movers`) moves the fluid mesh with the
structure (:mod:`tofsi.physics.mesh_motion`): two-way coupling, or the
mesh-motion commands' prescribed structure motion. The block's residual is
``D`` (a residual mover's; a path-dependent mover is the explicit map
``x - Phi(u, rho)``), its input the structure ``u``; its linearization is the
mover's tangent (or its vector-Jacobian product). The mesh's prescribed
values follow the structure, so its Jacobian keeps them (see
:meth:`movers.base.Mover.residual`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

import movers
from tofsi.core.blocks import ExplicitLinearization, FieldBlock, Linearization
from tofsi.core.config import build, coerce, documentation, option
from tofsi.core.errors import InputError
from tofsi.core.registry import FIELDS
from tofsi.fields.base import MOTION_ONLY, Field, Memory, Picture, on_q2_nodes, state_points
from tofsi.linalg import AMGSolver, RecyclingSolver, rigid_body_modes
from tofsi.mesh import quality
from tofsi.scene.settings import MAX_STIFFENING
from tofsi.scene.tables import SceneTable, mover_name, plain

if TYPE_CHECKING:
    from tofsi.physics.mesh_motion import MeshMotion


# ---- settings: the [mover] table -------------------------------------------------------------
BAND_MODES = ("off", "auto", "layers", "distance")


@dataclass(frozen=True)
class BandSettings:
    """Band-localized mesh motion (table ``[mover.band]``, see :mod:`tofsi.mesh.band`)."""

    mode: str = option("off", choices=BAND_MODES,
                       doc="off: the mover moves the whole fluid mesh; layers / distance: only the "
                           "quads within `layers` element layers / `distance` of the structure, the "
                           "band's outer edge held fixed; auto: the distance from the size of the motion")
    layers: int = option(8, ge=1, le=100_000, doc="element layers of the band (mode layers); the "
                                                   "least the band holds in mode auto")
    distance: float = option(0.1, gt=0, doc="reach of the band from the structure [m] (mode distance)")
    motion_multiple: float = option(15.0, gt=0, doc="mode auto: the band reaches this multiple of the "
                                                   "structure's largest displacement (when known: "
                                                   "mesh-motion scenes; else `layers`)")


LAYERS_FROM = ("density", "solid")


@dataclass(frozen=True)
class MoverSettings:
    """The mover and its parameters (``[mover]`` plus ``[mover.<name>]`` tables)."""

    name: str
    layers: tuple[float, ...] = ()
    params: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    layers_from: str = "density"
    band: BandSettings = dataclasses.field(default_factory=BandSettings)

    @property
    def options(self):
        """The selected mover's parameter record (None when mesh motion is off)."""
        return self.params.get(self.name)


def build_mover(raw, raw_scene) -> MoverSettings:
    if not isinstance(raw, dict):
        raise InputError("mover", raw, "expected a table")
    names = movers.available()
    raw = {k: v for k, v in raw.items() if k != "name"}
    layers = raw.pop("layers", [])
    layers_from = coerce(str, raw.pop("layers_from", "density"), "mover.layers_from",
                         dict(choices=LAYERS_FROM))
    band = build(BandSettings, raw.pop("band", {}), "mover.band")
    for key, value in raw.items():
        if key not in names:
            raise InputError(f"mover.{key}", value, "unknown key; allowed: name, layers, layers_from, "
                             "band, or a parameter table of one of " + ", ".join(map(repr, names)))
    factors = coerce(tuple[float, ...], layers, "mover.layers",
                     dict(gt=0, le=MAX_STIFFENING, doc="stiffening factor per element layer"))
    params = {n: build(movers.mover_class(n).Params, raw.get(n, {}), f"mover.{n}") for n in names}
    return MoverSettings(name=mover_name(raw_scene), layers=factors, params=MappingProxyType(params),
                         layers_from=layers_from, band=band)


def write_mover(mover: MoverSettings) -> dict:
    table = {"name": mover.name, "layers": list(mover.layers), "layers_from": mover.layers_from,
             "band": plain(mover.band)}
    table.update({name: plain(params) for name, params in mover.params.items()})
    return table


def mover_rows() -> list:
    rows = [("mover.name", "none", "none, " + ", ".join(movers.available()),
             "the mover (same setting as effects.mesh_motion)"),
            ("mover.layers", (), f"list of numbers, each 0 < value <= {MAX_STIFFENING:g}",
             "stiffening factor of each element layer counted from the interface"),
            ("mover.layers_from", "density", "one of 'density', 'solid'",
             "design scenes: count the layers from the evolving design (smooth dilation of the "
             "densities, gray elements partly stiffened, differentiable) or from the fixed solid only")]
    rows += documentation(BandSettings, "mover.band")
    for name in movers.available():
        rows += documentation(movers.mover_class(name).Params, f"mover.{name}")
    return rows


MOVER_TABLE = SceneTable("mover", MoverSettings, builder=build_mover, writer=write_mover, reference=mover_rows)


# ---- the block -------------------------------------------------------------------------------
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


class MotionBlock(FieldBlock):
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



# ---- the registry entry ----------------------------------------------------------------------
class MotionEntry(Field):
    """``x``: the fluid mesh's displacement, moved by the scene's mover (two-way coupling, or
    the mesh-motion commands' prescribed structure motion)."""

    name, title, tables = "x", "mesh motion", (MOVER_TABLE,)
    summary = ("min_skewness", "n_inverted")
    picture_names = ("mesh",)

    def active(self, scene, command="solve"):
        e = scene.effects
        if e.mesh_motion == "none":
            return False
        if command in MOTION_ONLY:
            return True
        return e.coupling == "two-way" and e.fluid != "none" and e.structure != "none"

    def memory(self, grid, scene):
        return Memory(2 * grid.nodes, "q1-vector", 2.15e3)

    def build(self, model):
        from tofsi.physics.mesh_motion import MeshMotion
        return MeshMotion(model.mesh, model.scene, linear_algebra=model.linear_algebra)

    def block(self, model, two_way):
        return MotionBlock(model.motion) if two_way else None

    def figures(self, model, state):
        """The moved fluid mesh's quality: smallest skewness, area change range, inverted quads."""
        if state.x is None:
            return {}
        q = quality.summary(model.mesh.points, state_points(model, state), model.mesh.quads)
        return {"min_skewness": q.min_skewness, "min_area_change": q.min_area_change,
                "max_area_change": q.max_area_change, "n_inverted": q.n_inverted}

    def point_data(self, model, state):
        if state.x is None:
            return {}
        return {"mesh_displacement": on_q2_nodes(model.mesh, state.mesh_displacement)}

    def pictures(self, model, state):
        if state.x is None:
            return []
        X = state_points(model, state)
        skew = quality.skewness(X, model.mesh.quads)
        return [Picture("mesh", "moved fluid mesh", quality.SKEWNESS_LABEL, skew, kind="mesh",
                        cmap="RdYlGn", points=X, vmin=min(0.0, float(skew.min())), vmax=1.0)]




FIELDS.register(MotionEntry())
