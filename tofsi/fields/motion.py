"""The fluid mesh's motion ``x``: its settings (``[mover]``), its block and its :class:`~tofsi.fields.base.Field` entry.

The scene's mover (package :mod:`movers`) moves the fluid mesh with the
structure (:mod:`tofsi.physics.mesh_motion`): two-way coupling, or the
mesh-motion commands' prescribed structure motion. The block's residual is
``D`` (a residual mover's), its input the structure ``u``; its linearization
is the mover's tangent. The mesh's prescribed values follow the structure,
so its Jacobian keeps them (see :meth:`movers.base.Mover.residual`).

A path-dependent mover (increments on the updated mesh) has no residual of
its own; its block eliminates it: the residual is ``x - M(u, rho)``, ``M``
the move, so ``dR/dx = I`` and the coupling ``dR/du = -dM/du`` is a
:class:`~tofsi.linalg.LinearMap` -- products by the move's tangent sweep,
transposed products by its reverse sweep, both from what the move stores
once (:class:`movers.incremental.IncrementDerivatives`). The monolithic
Newton takes it like any block (the block Gauss-Seidel preconditioner's
diagonal block is the identity; the whole Jacobian is never assembled), and
a partitioned sweep like the explicit map it is.
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
from tofsi.core.registry import FIELDS, MOVERS
from tofsi.fields.base import MOTION_ONLY, Field, Memory, Picture, on_q2_nodes, state_points
from tofsi.linalg import LinearMap, RecyclingSolver
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
    follow_density: float = 0.5

    @property
    def options(self):
        """The selected mover's parameter record (None when mesh motion is off)."""
        return self.params.get(self.name)


def build_mover(raw, raw_scene) -> MoverSettings:
    """The mover table: its keys and a parameter record for every mover that loads (a plugin
    that fails to import is passed over unless the scene names it, by ``mover.name`` or a
    ``[mover.<name>]`` table: then its error)."""
    if not isinstance(raw, dict):
        raise InputError("mover", raw, "expected a table")
    names = movers.available()
    raw = {k: v for k, v in raw.items() if k != "name"}
    layers = raw.pop("layers", [])
    layers_from = coerce(str, raw.pop("layers_from", "density"), "mover.layers_from",
                         dict(choices=LAYERS_FROM))
    band = build(BandSettings, raw.pop("band", {}), "mover.band")
    follow = coerce(float, raw.pop("follow_density", 0.5), "mover.follow_density", dict(gt=0, le=1))
    for key, value in raw.items():
        if key not in names:
            raise InputError(f"mover.{key}", value, "unknown key; allowed: name, layers, layers_from, "
                             "band, follow_density, or a parameter table of one of " + ", ".join(map(repr, names)))
    factors = coerce(tuple[float, ...], layers, "mover.layers",
                     dict(gt=0, le=MAX_STIFFENING, doc="stiffening factor per element layer"))
    selected = mover_name(raw_scene)
    classes = {cls.name: cls for cls in MOVERS}
    for name in {*raw, selected} - {"none"}:
        classes[name] = movers.mover_class(name)             # the error of a plugin the scene names
    params = {n: build(cls.Params, raw.get(n, {}), f"mover.{n}") for n, cls in sorted(classes.items())}
    return MoverSettings(name=selected, layers=factors, params=MappingProxyType(params),
                         layers_from=layers_from, band=band, follow_density=follow)


def write_mover(mover: MoverSettings) -> dict:
    table = {"name": mover.name, "layers": list(mover.layers), "layers_from": mover.layers_from,
             "follow_density": mover.follow_density, "band": plain(mover.band)}
    table.update({name: plain(params) for name, params in mover.params.items()})
    return table


def mover_rows(builtin: bool = False) -> list:
    names = MOVERS.builtin() if builtin else sorted(cls.name for cls in MOVERS)
    rows = [("mover.name", "none", "none, " + ", ".join(sorted(names)),
             "the mover (same setting as effects.mesh_motion)"),
            ("mover.layers", (), f"list of numbers, each 0 < value <= {MAX_STIFFENING:g}",
             "stiffening factor of each element layer counted from the interface"),
            ("mover.layers_from", "density", "one of 'density', 'solid'",
             "design scenes: count the layers from the evolving design (smooth dilation of the "
             "densities, gray elements partly stiffened, differentiable) or from the fixed solid only"),
            ("mover.follow_density", 0.5, "0 < value <= 1",
             "design scenes: a mesh node moves with the structure exactly (x = u) where one of its "
             "elements has at least this density; below, the mover takes over smoothly towards rho = 0")]
    rows += documentation(BandSettings, "mover.band")
    for name in sorted(names):
        rows += documentation(movers.mover_class(name).Params, f"mover.{name}", builtin)
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
        if self._solver is None:           # AMG-GMRES on the iterative path (the blended tangent is not symmetric)
            la, base = self.motion.linear_algebra, self.motion.base
            self._solver = RecyclingSolver(
                lambda A: la.elasticity(A, base.points, lambda: base.ordering, symmetric=False))
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


class MoveLinearization(ExplicitLinearization):
    """A path-dependent move ``x = M(u, rho)`` as the residual ``x - M``: ``matrix() = I``, the
    coupling ``-dM/du`` a :class:`~tofsi.linalg.LinearMap` (tangent and reverse sweeps through
    the move's increments), the transposed partials minus the reverse sweep. ``result``: the
    move at the point's ``u`` and ``rho``."""

    def __init__(self, block, fields, rho, params, result):
        motion = block.motion

        def vjp(x_bar):
            u_bar, rho_bar = motion.vjp(result, np.asarray(x_bar).reshape(-1, 2), rho)
            return {"u": u_bar}, rho_bar
        super().__init__(block, fields, rho, params, vjp)
        self.result = result

    @property
    def residual(self):
        return self.value - self.result.displacement.ravel()

    def coupling(self, other):
        if other != "u":
            return None
        motion, result, size = self.block.motion, self.result, self.block.size
        # the map's products must not reach back to this linearization (a cycle would leave the
        # move's stored increments, factorizations included, to the cyclic garbage collector)
        return self.kept("D_u", lambda: LinearMap(
            (size, size), lambda v: -motion.jvp(result, v),
            lambda w: -motion.structure_vjp(result, np.asarray(w).reshape(-1, 2))))


class MotionBlock(FieldBlock):
    """The fluid-mesh displacement ``x``: the scene's mover driven by the structure."""

    name, symbol, report_name = "x", "D", "mover"
    inputs = ("u",)

    def __init__(self, motion: MeshMotion):
        self.motion = motion
        self.size = 2 * motion.mesh.n_nodes
        self.explicit = motion.path_dependent      # the residual x - M(u, rho) of a move in increments
        self.matrix_free_couplings = ("u",) if self.explicit else ()
        self.slow_couplings = ("u",) if self.explicit else ()   # its tangent: a store per move
        self.takes_tolerance = motion.takes_tolerance           # solve() takes a sweep's ``tol``

    @property
    def fixed(self):
        return self.motion.fixed_dofs

    def initial(self, fields, rho, params):
        return np.zeros(self.size)

    def residual(self, fields, rho, params):
        if self.explicit:
            return fields["x"] - self.motion.move(fields["u"], rho).displacement.ravel()
        return self.motion.residual(fields["x"], fields["u"], rho, jacobian=False)[0]

    def linearize(self, fields, rho, params):
        if self.explicit:
            return MoveLinearization(self, fields, rho, params, self.motion.move(fields["u"], rho))
        return MotionLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None, tol=None):
        """The mover's move with the structure's ``u``, warm started from ``guess`` and
        ``previous``'s solver; ``tol`` (a mover that takes one): its Newton only to that
        residual relative to its force scale (a starting sweep's)."""
        recycled = previous.solver if isinstance(previous, MotionLinearization) else None
        result = self.motion.move(fields["u"], rho, progress, initial=guess, solver=recycled,   # warm starts
                                  tol=tol)
        x = result.displacement.ravel()
        values = {**fields, "x": x}
        if self.explicit:
            lin = MoveLinearization(self, values, rho, params, result)
        else:
            lin = MotionLinearization(self, values, rho, params, solver=result.solver)
        return x, lin, result.report.as_dict()

    def residual_scale(self, fields, rho, params, lin):
        x = fields["x"]
        return max(float(np.linalg.norm(lin.residual)), float(np.linalg.norm(lin.matrix() @ x)), 1e-300)

    def ordering_grid(self):
        return np.repeat(self.motion.mesh.grid_positions(), 2, axis=0), np.zeros(self.size, dtype=bool)

    def ordering(self):
        return self.motion.base.ordering



# ---- the registry entry ----------------------------------------------------------------------
class MotionEntry(Field):
    """``x``: the fluid mesh's displacement, moved by the scene's mover (two-way coupling, or
    the mesh-motion commands' prescribed structure motion)."""

    name, title, tables = "x", "mesh motion", (MOVER_TABLE,)
    summary = ("min_skewness", "n_inverted", "max_interface_gap")
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

    def block(self, model, stage):
        return MotionBlock(model.motion) if stage.coupling == "two-way" else None

    def figures(self, model, state):
        """The moved fluid mesh's quality (smallest skewness, area change range, inverted quads)
        and how far it leaves the structure on the solid (``max_interface_gap`` [m])."""
        if state.x is None:
            return {}
        q = quality.summary(model.mesh.points, state_points(model, state), model.mesh.quads)
        gap = {} if state.u is None else {"max_interface_gap": model.motion.interface_gap(state.x, state.u, state.rho)}
        return {"min_skewness": q.min_skewness, "min_area_change": q.min_area_change,
                "max_area_change": q.max_area_change, "n_inverted": q.n_inverted, **gap}

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
