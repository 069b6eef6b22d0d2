"""Stiffening factors tuned by gradients: the mover's quality as an optimization problem.

Abdelhamid & Czekanski grid-search the stiffening factors of the first element
layers (1 to 6 per layer). Here NLopt chooses them, with exact gradients:

    maximize    Q(z) = KS_p(corner skewness of X + x(f(z)))
    subject to  KS-max of A/A0 <= max_area_change,  KS-min of A/A0 >= min_area_change  (optional)

``x(f)`` the scene's mover (:class:`~tofsi.physics.mesh_motion.MeshMotion`,
explicit-interface form, the band if the scene has one) with per-quad
stiffening factors ``f``, ``KS_p`` the Kreisselmeier-Steinhauser soft minimum
(:mod:`tofsi.mesh.soft_quality`, parameters ``p`` in ``tune.ks``: a continuation, each
stage of the optimization sharper than the last). The design ``z`` is
mapped to the factors by a :class:`Parametrization`:

* ``layers`` -- one factor per element layer counted from the interface,
  ``f_e = exp(z_k)`` on layer ``k <= K``, 1 beyond (log factors: the scale
  of a stiffness is multiplicative);
* ``profile`` -- a factor decaying with the layer number ``k`` (the element
  distance from the interface), ``f_k = 1 + a exp(-(k - 1) / L)``, ``z = (a, log L)``.

The gradient is the chain ``dQ/dz = (dx/df)^T dQ/dx . df/dz``: ``dQ/dx`` from
:func:`~tofsi.mesh.soft_quality.corner_skewness_vjp`, ``(dx/df)^T`` the mover's
vector-Jacobian product (one transposed tangent solve for the residual movers,
linear and Yeoh; the reverse sweep through the increments for the spring
analogy), so one evaluation costs one move and one adjoint per function.
Inverted meshes are accepted while tuning: the soft measure stays continuous
where a corner folds over, so a start where the mover inverts elements still
has a gradient that points back to valid meshes.
The tuned factors are the evaluated point with the highest true minimum
skewness (among those that meet the area bounds).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import nlopt
import numpy as np

from tofsi.core.errors import InputError, NumericalError
from tofsi.mesh.layers import element_layers
from tofsi.coupling.motion import MotionSetup, motion_setup
from tofsi.mesh.quality import area_change, inverted, skewness
from tofsi.mesh.soft_quality import area_change_vjp, corner_skewness, corner_skewness_vjp, soft_max, soft_min

log = logging.getLogger(__name__)
ALGORITHMS = {"SLSQP": nlopt.LD_SLSQP, "MMA": nlopt.LD_MMA, "CCSAQ": nlopt.LD_CCSAQ,
              "LBFGS": nlopt.LD_LBFGS}


# ---- parametrizations: design z -> factor per layer -> factor per moving quad -------------
class Parametrization:
    """``z`` -> factor per layer ``(K,)``; the quad factors are ``table[layer]`` (1 outside)."""

    def __init__(self, layer: np.ndarray):
        self.layer = layer                    # (Em,) layer of each moving quad, 0: none
        self.n_layers = int(layer.max())

    def layer_factors(self, z: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def layer_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``d layer_factors / dz`` ``(K, len(z))``."""
        raise NotImplementedError

    def factors(self, z: np.ndarray) -> np.ndarray:
        """Stiffening factor of every moving quad ``(Em,)``."""
        table = np.r_[1.0, self.layer_factors(z)]
        return table[self.layer]

    def transpose(self, z: np.ndarray, f_bar: np.ndarray) -> np.ndarray:
        """``(df/dz)^T f_bar`` for quad adjoints ``f_bar (Em,)``."""
        per_layer = np.bincount(self.layer, f_bar, minlength=self.n_layers + 1)[1:]
        return self.layer_jacobian(z).T @ per_layer


class LayerFactors(Parametrization):
    """One factor per layer ``1..K``: ``f_k = exp(z_k)``."""

    def __init__(self, layer, n_layers: int, lower: float, upper: float, start=()):
        super().__init__(np.where(layer <= n_layers, layer, 0))
        self.n_layers = n_layers
        if not len(start):                       # a mild decay, 2, 1.5, 1.25, ...: a scale to start from
            start = 1.0 + 0.5 ** np.arange(n_layers)
        start = list(start)[:n_layers] + [1.0] * max(0, n_layers - len(start))
        self.x0 = np.log(np.clip(start, lower, upper))
        self.lower, self.upper = np.full(n_layers, np.log(lower)), np.full(n_layers, np.log(upper))

    def layer_factors(self, z):
        return np.exp(z)

    def layer_jacobian(self, z):
        return np.diag(np.exp(z))

    def describe(self, z) -> dict:
        return {"layer_factors": [float(v) for v in np.exp(z)]}


class DecayingProfile(Parametrization):
    """``f_k = 1 + a exp(-(k - 1) / L)`` over every layer; ``z = (a, log L)``, L in layers."""

    def __init__(self, layer, lower: float, upper: float):
        super().__init__(layer)
        self.x0 = np.array([min(1.0, upper - 1.0), np.log(2.0)])
        self.lower = np.array([lower - 1.0, np.log(0.25)])
        self.upper = np.array([upper - 1.0, np.log(max(self.n_layers, 1.0))])

    def layer_factors(self, z):
        k = np.arange(self.n_layers)
        return 1.0 + z[0] * np.exp(-k / np.exp(z[1]))

    def layer_jacobian(self, z):
        k = np.arange(self.n_layers)
        decay = np.exp(-k / np.exp(z[1]))
        return np.column_stack([decay, z[0] * decay * k / np.exp(z[1])])

    def describe(self, z) -> dict:
        f = self.layer_factors(z)
        shown = int(np.sum(f - 1.0 > 1e-3 * max(abs(z[0]), 1e-300))) or 1
        return {"amplitude": float(z[0]), "decay_layers": float(np.exp(z[1])),
                "layer_factors": [float(v) for v in f[:shown]]}


def parametrization(setup: MotionSetup, settings, start=()) -> Parametrization:
    """The scene's parametrization over the moving quads of ``setup``."""
    mesh, motion = setup.mesh, setup.motion
    movable = np.zeros(mesh.n_elements, dtype=bool)
    movable[motion.moving] = True
    if settings.parametrization == "layers":
        layer = element_layers(mesh.incidence, mesh.interface_nodes, movable, settings.layers)
        return LayerFactors(layer[motion.moving], settings.layers, settings.min_factor,
                            settings.max_factor, start)
    layer = element_layers(mesh.incidence, mesh.interface_nodes, movable)
    return DecayingProfile(layer[motion.moving], settings.min_factor, settings.max_factor)


# ---- the functions of the tuning problem ---------------------------------------------------
@dataclass
class Evaluation:
    """One mover solve at design ``z``: its figures, and what the adjoints need."""

    z: np.ndarray
    factors: list
    min_skewness: float
    min_area_change: float
    max_area_change: float
    n_inverted: int
    soft_min_skewness: float = np.nan        # at the KS parameter of the stage that evaluated it
    ks: float = np.nan
    result: object = field(default=None, repr=False)
    problem: object = field(default=None, repr=False)

    @property
    def moved(self) -> np.ndarray:
        return self.problem.points + self.result.displacement

    def row(self) -> dict:
        return {"factors": self.factors, "ks": self.ks, "soft_min_skewness": self.soft_min_skewness,
                "min_skewness": self.min_skewness, "min_area_change": self.min_area_change,
                "max_area_change": self.max_area_change, "n_inverted": self.n_inverted}


class TuningProblem:
    """Soft minimum skewness and soft area-change bounds as functions of ``z``, with gradients.

    Each new ``z`` costs one move (counted in ``moves``); each gradient one
    vector-Jacobian product of the mover (``adjoints``); ``solves`` counts both. The last move is kept
    for the objective and the constraints at the same ``z``. The KS parameter
    ``p`` is an input of every function (it may change between stages).
    """

    def __init__(self, setup: MotionSetup, settings, param: Parametrization):
        self.setup, self.settings, self.param = setup, settings, param
        self.mover = setup.motion.mover
        self.base = dataclasses.replace(setup.problem, accept_inverted=True)
        self.target = setup.motion.target(setup.prescribed)
        self.moves = self.adjoints = 0
        self.history: list[Evaluation] = []

    @property
    def solves(self) -> int:
        return self.moves + self.adjoints

    def known(self, z) -> Evaluation | None:
        """The kept move at ``z``, if any (the last one and the best one are kept)."""
        for ev in reversed(self.history):
            if ev.result is not None and np.array_equal(ev.z, z):
                return ev
        return None

    def best(self) -> Evaluation | None:
        """The evaluation with the highest minimum skewness among those meeting the area bounds
        (among all when none does)."""
        candidates = [ev for ev in self.history if self.feasible(ev)] or self.history
        return max(candidates, key=lambda ev: ev.min_skewness) if candidates else None

    def evaluate(self, z: np.ndarray) -> Evaluation:
        """The move at ``z`` (a kept one when ``z`` was evaluated before)."""
        z = np.array(z, dtype=float)
        ev = self.known(z)
        if ev is not None:
            return ev
        problem = self.base.with_data(stiffening=self.param.factors(z))
        self.moves += 1
        result = self.mover.move(problem, self.target)
        moved, quads = problem.points + result.displacement, problem.quads
        ratio = area_change(problem.points, moved, quads)
        ev = Evaluation(z, self.param.describe(z)["layer_factors"], float(skewness(moved, quads).min()),
                        float(ratio.min()), float(ratio.max()), int(inverted(moved, quads).sum()),
                        result=result, problem=problem)
        self.history.append(ev)
        best = self.best()
        for other in self.history[:-1]:               # keep the solvers of the last and the best only
            if other is not best:
                other.result = other.problem = None
        return ev

    def _chain(self, ev: Evaluation, x_bar: np.ndarray) -> np.ndarray:
        """``dQ/dz`` from ``x_bar = dQ/dx`` ``(n, 2)``: the mover's VJP, then the parametrization."""
        self.adjoints += 1
        _, f_bar, _ = self.mover.vjp(ev.problem, ev.result, x_bar)
        return self.param.transpose(ev.z, f_bar)

    def objective(self, z, grad: np.ndarray | None, p: float) -> float:
        """``KS_p`` of the corner skewness (maximized)."""
        ev = self.evaluate(z)
        quads = ev.problem.quads
        value, w = soft_min(corner_skewness(ev.moved, quads), p)
        ev.soft_min_skewness, ev.ks = value, p
        if grad is not None and grad.size:
            grad[:] = self._chain(ev, corner_skewness_vjp(ev.moved, quads, w))
        return value

    def area_bound(self, z, grad, p: float, upper: bool) -> float:
        """``KSmax(A/A0) - max`` (upper) or ``min - KSmin(A/A0)`` (lower); feasible ``<= 0``."""
        ev = self.evaluate(z)
        s = self.settings
        X, quads = ev.problem.points, ev.problem.quads
        ratio = area_change(X, ev.moved, quads)
        soft, w = (soft_max if upper else soft_min)(ratio, p)
        value = soft - s.max_area_change if upper else s.min_area_change - soft
        if grad is not None and grad.size:
            x_bar = area_change_vjp(X, ev.moved, quads, w)
            grad[:] = self._chain(ev, x_bar if upper else -x_bar)
        return float(value)

    def feasible(self, ev: Evaluation, tol: float = 1e-9) -> bool:
        """The evaluation meets the area bounds (its true minimum and maximum)."""
        s = self.settings
        return ((not s.max_area_change or ev.max_area_change <= s.max_area_change + tol)
                and (not s.min_area_change or ev.min_area_change >= s.min_area_change - tol))


# ---- the driver ------------------------------------------------------------------------------
@dataclass
class TuneResult:
    """Tuned factors and the quality they give; ``history`` holds every evaluation's figures."""

    parametrization: str
    design: dict
    layer_factors: list
    min_skewness: float
    soft_min_skewness: float
    min_area_change: float
    max_area_change: float
    n_inverted: int
    moves: int
    adjoints: int
    stop: str
    wall_time_s: float
    history: list
    best: Evaluation = field(repr=False, default=None)

    def figures(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in ("best", "history")}


def tune(scene, progress=None, setup: MotionSetup | None = None) -> TuneResult:
    """Tune the scene's stiffening factors (``[tune]`` settings); returns a :class:`TuneResult`.

    The optimization starts from the scene's ``mover.layers`` (1 beyond them), or, when it
    gives none, from the mild decay ``f_k = 1 + 2^(1-k)`` (2, 1.5, 1.25, ...); it
    runs one NLopt stage per KS parameter in ``tune.ks`` (continuation: each stage starts
    from the best point so far; evaluations a stage leaves unused pass to the next).
    """
    s = scene.tune
    if scene.has_design:
        raise InputError("geometry.design", list(scene.geometry.design), "tofsi tune works on "
                         "mesh-motion scenes (an explicit structure, no design region)")
    if s.algorithm == "LBFGS" and (s.min_area_change or s.max_area_change):
        raise InputError("tune.algorithm", s.algorithm, "LBFGS takes no constraints; with area "
                         "bounds use SLSQP, MMA or CCSAQ")
    t0 = time.perf_counter()
    setup = setup or motion_setup(scene)
    if setup.motion.mover.kinks:
        log.warning("tune: the %s mover's map is not smooth: %s", scene.mover.name, setup.motion.mover.kinks)
    param = parametrization(setup, s, scene.mover.layers)
    problem = TuningProblem(setup, s, param)
    z = np.clip(param.x0, param.lower, param.upper)
    stop = ""
    for stage, p in enumerate(s.ks):
        budget = (s.max_solves - problem.solves) // (len(s.ks) - stage)
        if budget < 1:
            break
        stop = _stage(problem, param, z, p, budget, progress)
        if stop.startswith("mover failed") or problem.best() is None:
            break
        z = problem.best().z
    best = problem.best()
    if best is None:
        raise NumericalError(f"tune: no mover solve succeeded ({stop})", {"stop": stop})
    return TuneResult(s.parametrization, param.describe(best.z), best.factors, best.min_skewness,
                      best.soft_min_skewness, best.min_area_change, best.max_area_change, best.n_inverted,
                      problem.moves, problem.adjoints, stop, time.perf_counter() - t0,
                      [ev.row() for ev in problem.history], best)


def _stage(problem: TuningProblem, param: Parametrization, z0, p: float, budget: int, progress) -> str:
    """One NLopt run at KS parameter ``p`` from ``z0`` with at most ``budget`` mover solves
    (a new point costs a move and one adjoint per function); the reason it stopped."""
    s = problem.settings
    opt = nlopt.opt(ALGORITHMS[s.algorithm], param.x0.size)
    opt.set_lower_bounds(param.lower)
    opt.set_upper_bounds(param.upper)
    limit = problem.solves + budget
    gradients = 1 + bool(s.max_area_change) + bool(s.min_area_change)
    failed = []

    def objective(z, grad):
        cost = gradients + (problem.known(z) is None)
        if problem.solves + cost > limit:
            raise nlopt.ForcedStop                      # the stage's solves are spent
        try:
            value = problem.objective(z, grad, p)
        except NumericalError as err:                   # the mover cannot reach this point
            failed.append(f"mover failed at factors {param.describe(z)['layer_factors']}: {err}")
            log.warning("tune: %s", failed[-1])
            raise nlopt.ForcedStop from err
        ev = problem.history[-1]
        if progress:
            progress(problem.solves, s.max_solves, {"min_skewness": ev.min_skewness})
        log.info("tune %d (p = %g): factors %s soft min %.4f min skewness %.4f", problem.moves, p,
                 np.round(ev.factors, 3).tolist(), value, ev.min_skewness)
        return value

    opt.set_max_objective(objective)
    if s.max_area_change:
        opt.add_inequality_constraint(lambda z, g: problem.area_bound(z, g, p, upper=True), 1e-6)
    if s.min_area_change:
        opt.add_inequality_constraint(lambda z, g: problem.area_bound(z, g, p, upper=False), 1e-6)
    opt.set_ftol_abs(s.tol_objective)
    try:
        opt.optimize(z0)
        return _STOPS.get(opt.last_optimize_result(), "stopped")
    except nlopt.ForcedStop:
        return failed[0] if failed else "tune.max_solves reached"
    except (RuntimeError, ValueError) as err:           # NLopt's roundoff-limited and similar ends
        return f"nlopt: {err}"


_STOPS = {nlopt.SUCCESS: "success", nlopt.STOPVAL_REACHED: "stop value reached",
          nlopt.FTOL_REACHED: "objective change below tune.tol_objective",
          nlopt.XTOL_REACHED: "design change below tolerance",
          nlopt.MAXEVAL_REACHED: "evaluation limit", nlopt.MAXTIME_REACHED: "time limit"}
