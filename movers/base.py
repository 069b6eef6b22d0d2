"""The interface every mover implements, and what movers share.

A mover moves the nodes of a set of quads (the fluid mesh) so that nodes
with prescribed motion (the structure and the channel walls) end where they
are told, and returns the displacement of every node with a report.

    result = mover.move(problem, prescribed)      # prescribed: (n, 2) [m]
    result.displacement                           # (n, 2) [m]
    result.report.converged, result.report.quality[-1]["min_skewness"]

The mesh it works on is a :class:`~movers.problem.MotionProblem`
(importable from here too). Nodes not used by any moving quad are held at
their prescribed value. A mover that cannot deliver a valid mesh raises
:class:`tofsi.core.errors.NumericalError` (exit status 3) whose diagnostic holds
the report so far and the worst element.
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field
from typing import Callable, ClassVar

import numpy as np

from movers.blend import Blend, node_scale
from movers.failure import at
from tofsi.mesh import quality
from tofsi.core.errors import NumericalError
from tofsi.core.kept import Kept, input_key
from tofsi.fem.assembly import assemble_vector
from tofsi.fem.complex_step import derivative
from tofsi.linalg import LinearAlgebra, RecyclingSolver
from movers.increment_solvers import solvers_for
from movers.problem import MotionProblem

log = logging.getLogger(__name__)


def element_apply(Ke: np.ndarray, v: np.ndarray, dofs: np.ndarray, transpose: bool = False) -> np.ndarray:
    """Global ``K v`` (or ``K^T v``) from element matrices ``(E, a, a)``, without assembling ``K``."""
    spec = "eba,eb->ea" if transpose else "eab,eb->ea"
    return assemble_vector(dofs, np.einsum(spec, Ke, v[dofs]), v.size)

Progress = Callable[[int, int, dict], None]


def transposed_solve(problem: "MotionProblem", Ke: np.ndarray, rhs: np.ndarray, solver, blend=None, A=None):
    """Adjoint of ``[[W K_ff + S_c, W K_fp], [0, I]]`` (element matrices ``Ke`` of ``K``; ``A``, the
    constrained matrix of the free block, when already assembled).

    Returns ``lam`` (zero on fixed dofs) and ``lam_p`` (zero on free dofs):
    ``A_ff^T lam_f = rhs_f``, ``lam_p = rhs_p - (K^T W lam_f)_p``, with the same
    Dirichlet operator as the forward solve, homogeneous.
    """
    bc, dofs = problem.bc, problem.dofs
    if A is None:
        A = bc.matrix(Ke) if blend is None else blend.matrix(bc, Ke, dofs)
    lam = solver.solve_transpose(A, bc.homogenize(rhs))
    lam[bc.fixed] = 0.0
    lam_w = lam if blend is None else blend.weighted(lam)
    lam_p = np.zeros_like(rhs)
    lam_p[bc.fixed] = rhs[bc.fixed] - element_apply(Ke, lam_w, dofs, transpose=True)[bc.fixed]
    return lam, lam_p


@dataclass
class MoveReport:
    """What happened during a move; every field is JSON-friendly."""

    mover: str
    converged: bool = False
    increments: int = 0
    newton_iterations: int = 0
    linear_solves: int = 0
    factorizations: int = 0
    krylov_iterations: int = 0
    cutbacks: int = 0
    warm_start: bool = False                                # started from a given nearby displacement
    residual_history: list = field(default_factory=list)   # per increment: list of norms
    quality: list = field(default_factory=list)            # per increment: summary dict
    wall_time_s: float = 0.0
    message: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class MoveResult:
    displacement: np.ndarray      # (n, 2) [m]
    report: MoveReport
    cell_data: dict = field(default_factory=dict)   # per moving quad, e.g. the spring diagonals
    trajectory: list | None = None                  # [x_0, ..., x_N] of path-dependent movers
    solver: object = None                           # the forward solver, reused by the adjoint
    blend: object = None                            # the movers.blend.Blend used, if any
    target: np.ndarray | None = None                # (2n,) the prescribed motion as applied
    problem: object = None                          # the MotionProblem moved (set by callers)
    record: object = None                           # a move in increments: what its derivatives reuse
    derivatives: object = None                      # a path-dependent move's stored increments (built by its JVP or VJP)


def quality_record(problem: MotionProblem, x: np.ndarray, load: float) -> dict:
    """Quality summary of the moving quads at displacement ``x`` ``(n, 2)``; the worst element
    by the mesh's numbering (``problem.element_ids``), at its reference centre [m]."""
    s = quality.summary(problem.points, problem.points + x, problem.quads)
    return {"load": float(load), "min_skewness": s.min_skewness,
            "min_area_change": s.min_area_change, "max_area_change": s.max_area_change,
            "n_inverted": s.n_inverted, "worst_element": int(problem.element_ids[s.min_skewness_element]),
            "worst_location": list(s.min_skewness_location)}


class Mover(ABC):
    """Base class of mesh movers: ``Params`` record, ``move``, and what the adjoint needs.

    A mover with a residual form (``path_dependent`` False) writes its element
    kernel, :meth:`element_residual`, and :meth:`move`; this class composes
    from the kernel the density blend, the fixed rows, the residual and its
    true Jacobian, the residual's partial derivatives and the
    implicit-function vector-Jacobian product. A path-dependent mover
    (increments on the updated mesh) writes :meth:`move`, :meth:`jvp`, :meth:`vjp` and
    :meth:`reference_matrices` instead. A mover that sets ``warm_starts``
    takes ``initial`` (a nearby displacement to start from) and ``solver`` (an
    earlier move's solver to recycle) in :meth:`move`; its result must not
    depend on them beyond its own tolerance.
    """

    name: ClassVar[str]
    Params: ClassVar[type]
    warm_starts: ClassVar[bool] = False     # move() takes ``initial``, a nearby displacement to start from
    takes_tolerance: ClassVar[bool] = False  # move() takes ``tol``, a looser Newton tolerance

    def __init__(self, params):
        self.params = params
        self.kept_scale = Kept()        # the blend's node scale, keyed by the mesh and the params

    @abstractmethod
    def move(self, problem: MotionProblem, prescribed: np.ndarray,
             progress: Progress | None = None) -> MoveResult:
        """Displacement ``(n, 2)`` with the fixed nodes at ``prescribed`` and a report."""

    @property
    def path_dependent(self) -> bool:
        """True when the map has no residual form (increments on the updated mesh)."""
        return False

    def increment_solvers(self, problem: MotionProblem):
        """What a mover in increments (:attr:`path_dependent`) keeps across its moves at one
        design (``problem``'s densities), passed back to :meth:`move` as ``solver``: its
        increments' sparse LU factors (:class:`movers.increment_solvers.IncrementSolvers`); None
        for a mover with a residual form, or with an iterative tangent solver."""
        return solvers_for(problem, self.params) if self.path_dependent else None

    @property
    def inversion_hint(self) -> str:
        """What to try when a move inverts elements (for the command line's message): more
        increments for a mover that applies the motion in increments."""
        n = getattr(self.params, "increments", None)
        if n is None or not self.path_dependent:
            return ""
        return (f"the {self.name} mover inverted elements with mover.{self.name}.increments = {n}; "
                f"try more increments (e.g. --set mover.{self.name}.increments={max(2 * n, 10)})")

    @property
    def kinks(self) -> str:
        """Why the map is not smooth in its inputs (a discrete choice that switches as they
        change, which a gradient holds fixed); ``""`` for a smooth map."""
        return ""

    # ---- the residual form, composed from the element kernel ------------------------
    def element_residual(self, problem: MotionProblem, x: np.ndarray, factors, tangent: bool = True):
        """Element residuals ``(Em, 8)`` and tangents ``(Em, 8, 8)`` (None without ``tangent``)
        of the unblended mover at displacement ``x`` (2n,), stiffening ``factors`` (Em,)
        (complex-safe in ``factors``); raises NumericalError where it is undefined."""
        raise NotImplementedError(f"the {self.name} mover has no residual form "
                                  "(increments on the updated mesh); use its vector-Jacobian product")

    def reference_matrices(self, problem: MotionProblem) -> np.ndarray:
        """Unstiffened element matrices ``(Em, 8, 8)`` of the reference mesh (blend scale)."""
        return self.element_residual(problem, np.zeros(2 * problem.n_nodes),
                                     np.ones(len(problem.quads)))[1]

    def blend(self, problem: MotionProblem) -> Blend | None:
        """The :class:`~movers.blend.Blend` of a density-blended problem (None otherwise)."""
        if problem.blend is None:
            return None
        c = self.kept_scale.get(input_key(problem.points, problem.quads, self.params),
                                lambda: node_scale(self.reference_matrices(problem), problem.dofs, problem.n_nodes))
        return Blend.build(np.asarray(problem.blend, float), c, problem.bc.is_fixed)

    def residual(self, problem: MotionProblem, x: np.ndarray, target: np.ndarray, blend=None,
                 jacobian: bool = True):
        """``D(x)`` (2n,) and its true Jacobian ``D_x`` (CSR; None without ``jacobian``).

        Free rows ``W R(x) + S_c (x - target)`` (``W = 1``, ``S_c = 0`` without a
        blend), fixed rows ``x - target``; ``D_x`` keeps the free rows' fixed
        columns (the fixed values follow another field). ``blend``: the
        problem's :class:`~movers.blend.Blend` if already built.
        """
        blend = self.blend(problem) if blend is None else blend
        x = np.asarray(x, float).reshape(-1)
        target = np.asarray(target, float).reshape(-1)
        Re, Ke = self.element_residual(problem, x, problem.stiffening, tangent=jacobian)
        bc, dofs = problem.bc, problem.dofs
        r = assemble_vector(dofs, Re, x.size)
        if blend is not None:
            r = blend.residual(r, x, target)
        r = bc.homogenize(r)
        r[bc.fixed] = (x - target)[bc.fixed]
        if not jacobian:
            return r, None
        K = bc.row_matrix(Ke).tocsr() if blend is None else blend.row_matrix(bc, Ke, dofs)
        return r, K

    def residual_partials(self, problem: MotionProblem, x, target, lam, blend=None):
        """``lam^T dD/d(target, stiffening, blend)``: ``(2n,)``, ``(Em,)``, ``(n,)`` (no solve).

        ``-(lam_p + S_c lam_f)`` on the target; ``(W lam)_e . dR_e/df_e`` on the
        factors (complex step in the factor); ``lam_i . (c_i (x_i - target_i) - R_i)``
        on the blend.
        """
        blend = self.blend(problem) if blend is None else blend
        x = np.asarray(x, float).reshape(-1)
        target = np.asarray(target, float).reshape(-1)
        lam = np.asarray(lam, float).reshape(-1)
        bc, dofs = problem.bc, problem.dofs
        lam_f = bc.homogenize(lam)
        t_bar = np.zeros_like(lam)
        t_bar[bc.fixed] = -lam[bc.fixed]
        lam_w = lam_f if blend is None else blend.weighted(lam_f)
        dR_df = derivative(lambda f: self.element_residual(problem, x, f, tangent=False)[0],
                           problem.stiffening)     # R_e depends on f_e alone: one step for all
        f_bar = np.einsum("ea,ea->e", lam_w[dofs], dR_df)
        s_bar = np.zeros(problem.n_nodes)
        if blend is not None:
            R = assemble_vector(dofs, self.element_residual(problem, x, problem.stiffening, False)[0], x.size)
            t_blend, s_bar = blend.partials(lam_f, x, target, R)
            t_bar += t_blend
        return t_bar, f_bar, s_bar

    def transposed_solve(self, problem: MotionProblem, x, rhs, solver=None, blend=None):
        """``D_x^T lam = rhs`` at ``x``: ``(lam_f, lam_p)``, zero on the fixed (free) dofs.

        ``A_ff^T lam_f = rhs_f`` with the free block of ``W K + S_c``, then
        ``lam_p = rhs_p - (K^T W lam_f)_p`` -- the same Dirichlet operator as the
        forward solve, homogeneous. ``solver``: the forward solve's
        :class:`~tofsi.linalg.RecyclingSolver` (its factorization preconditions).
        """
        blend = self.blend(problem) if blend is None else blend
        _, Ke = self.element_residual(problem, np.asarray(x, float).reshape(-1), problem.stiffening)
        return transposed_solve(problem, Ke, np.asarray(rhs, float).reshape(-1),
                                solver or self._solver(problem), blend)

    def vjp(self, problem: MotionProblem, result: MoveResult, xbar: np.ndarray):
        """Vector-Jacobian product of the map (prescribed, stiffening, blend) -> displacement.

        xbar : (n, 2) adjoint of the displacement; returns
        ``(prescribed_bar (n, 2), stiffening_bar (Em,), blend_bar (n,))``. For a
        residual mover the implicit-function adjoint at the equilibrium: one
        transposed tangent solve ``D_x^T lam = xbar``, then ``-(lam^T dD/d(target, f, s))``.
        """
        x = np.asarray(result.displacement, float).reshape(-1)
        lam, lam_p = self.transposed_solve(problem, x, xbar, result.solver, result.blend)
        t_bar, f_bar, s_bar = self.residual_partials(problem, x, result.target, lam + lam_p, result.blend)
        return -t_bar.reshape(-1, 2), -f_bar, -s_bar

    def jvp(self, problem: MotionProblem, result: MoveResult, t_dot: np.ndarray) -> np.ndarray:
        """Tangent of a path-dependent map along a change ``t_dot`` (n, 2) of the prescribed motion,
        stiffening and blend held: ``x_dot`` (n, 2). (A residual mover's tangent is its residual's
        Jacobian, :meth:`residual`.)"""
        raise NotImplementedError(f"the {self.name} mover has a residual form; use its Jacobian")

    # helpers ---------------------------------------------------------------
    def _solver(self, problem: MotionProblem) -> RecyclingSolver:
        """A solver for the mover's sequence of tangent/stiffness systems."""
        la = problem.linear_algebra or LinearAlgebra.default()
        amg = getattr(self.params, "tangent_solver", "direct") == "amg"     # a mover without the key: LU
        tol = getattr(self.params, "linear_tol", 1e-10)
        symmetric = problem.blend is None            # the blended form is not symmetric
        return RecyclingSolver(lambda K: la.elasticity(K, problem.points, lambda: problem.ordering, tol=tol,
                                                       symmetric=symmetric, amg=amg), rtol=tol)

    @staticmethod
    def _start(problem: MotionProblem, prescribed: np.ndarray):
        prescribed = np.asarray(prescribed, dtype=float)
        if prescribed.shape != (problem.n_nodes, 2):
            raise ValueError(f"prescribed displacement must be ({problem.n_nodes}, 2)")
        if not np.all(np.isfinite(prescribed)):
            raise NumericalError("prescribed displacement contains NaN or inf", {})
        if problem.blend is not None:               # the structure's motion everywhere
            return prescribed.reshape(-1).copy(), time.perf_counter()
        target = np.zeros(2 * problem.n_nodes)
        fixed = problem.fixed_dofs
        target[fixed] = prescribed.reshape(-1)[fixed]
        return target, time.perf_counter()

    @staticmethod
    def raise_failure(report: MoveReport, problem: MotionProblem, x: np.ndarray | None, message: str, t0: float,
              load: float = np.nan, broken: dict | None = None):
        """Raise the failure: ``message`` says what failed (and which element, where one did:
        ``broken``, kept in the diagnostic as ``broken_element``); ``x`` is the last accepted
        displacement at ``load`` (None: none is known), whose worst element the message adds
        only where the mesh had moved."""
        report.converged = False
        report.message = message
        report.wall_time_s = time.perf_counter() - t0
        diagnostic = {"report": report.as_dict(), **({"broken_element": broken} if broken else {})}
        where, state = "", None
        if x is not None:
            state = x.reshape(-1, 2)
            worst = quality_record(problem, state, load)
            diagnostic["quality"] = worst
            if not np.any(x):
                where = "; no load step was accepted (the mesh is as it was)"
            else:
                where = (f"; at the last accepted load {load:.4g} the worst element is "
                         f"{worst['worst_element']} (skewness {worst['min_skewness']:.3g}) at "
                         f"{at(worst['worst_location'])}")
        log.info("%s mover failed: %s", report.mover, message)   # the caller reports the error
        raise NumericalError(f"{report.mover} mover: {message}{where}", diagnostic, state=state)

    @staticmethod
    def _finish(report: MoveReport, problem: MotionProblem, x: np.ndarray, t0: float,
                solver: RecyclingSolver | None = None, trajectory=None, blend=None,
                target=None, record=None) -> MoveResult:
        report.wall_time_s = time.perf_counter() - t0
        if solver is not None:
            report.factorizations = solver.factorizations
            report.krylov_iterations = solver.krylov_iterations
        last = report.quality[-1] if report.quality else quality_record(problem, x.reshape(-1, 2), 1.0)
        if last["n_inverted"] and problem.accept_inverted:
            report.message = f"{last['n_inverted']} inverted element(s), accepted"
        elif last["n_inverted"]:
            report.converged = False
            report.message = (f"{last['n_inverted']} inverted element(s); worst element "
                              f"{last['worst_element']} (skewness {last['min_skewness']:.2g}) at "
                              f"{at(last['worst_location'])}")
            raise NumericalError(f"{report.mover} mover: {report.message}",
                                 {"report": report.as_dict(), "quality": last},
                                 state=x.reshape(-1, 2))
        report.converged = True
        return MoveResult(x.reshape(-1, 2), report, trajectory=trajectory, solver=solver, blend=blend,
                          target=target, record=record)
