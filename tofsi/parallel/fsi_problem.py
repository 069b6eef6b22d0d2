"""A compliance design problem of fluid-structure interaction with the flow by slabs, one-way or two-way.

:class:`DistributedFsiProblem` is the :class:`~tofsi.parallel.flow_problem.DistributedFlowProblem`
of a scene with a small-strain SIMP structure loaded by the flow (``design.objective =
"compliance"``), and in its two-way stages a fluid mesh moved by any mover block (Yeoh,
linear elasticity, the spring analogy in one increment or several -- a path-dependent move
enters as the explicit map ``x - M(u)``, its adjoint by the move's reverse sweep): the same answers as the serial
:class:`tofsi.optimization.problem.Problem` (to the solvers' tolerances), the flow solved
and differentiated by slabs.

What is distributed and what is replicated:

* the flow ``w``: Newton by slabs, its Jacobian, Krylov bases and hierarchies, and its
  transposed solve (:class:`~tofsi.parallel.flow_system.DistributedFlow`);
* the element sums coupling the flow to the rest -- the fluid load ``f(w, x, rho)``, its
  transposed partials in ``w``, ``x`` and ``rho``, the flow's shape derivative ``F_x^T lam``
  and friction derivative -- each rank on its own elements with the serial kernels
  (:class:`~tofsi.parallel.slab_flow.SlabCoupling`), summed over ranks;
* the structure's ``K_s(rho)``: assembled by the same slabs, factorized across the ranks by
  MUMPS once per design (:class:`~tofsi.parallel.slab_structure.SlabStructure`);
* the mesh motion of a mover with a residual form (Yeoh, linear elasticity or the spring in
  one increment): its element residuals and tangents on each rank's elements with the serial
  kernel, its tangent assembled by the same slabs and factorized across the ranks by MUMPS,
  Newton with the Yeoh mover's load steps, cutbacks and line search, its transposed solve and
  transposed partials likewise (:class:`~tofsi.parallel.slab_mover.SlabMover`);
* a move in increments (the spring analogy or linear elasticity in several): each increment's
  element matrices on the rank's elements, its system by the same slabs and MUMPS, the reverse
  sweep likewise (:class:`~tofsi.parallel.slab_increments.SlabIncrementMover`);
* replicated on every rank: the vectors ``u``, ``x``, ``f`` (``O(n)``, the same bits on
  every rank; a move's ``x_k`` per increment), the mover's design data (blend indicator,
  density-grown stiffening factors and their chain rule to ``rho``, ``O(E)``).

The two-way cycle ``x -> w -> f -> u -> x~ = D^-1(u)`` is solved partitioned: the fixed
point ``x = x~(x)`` by IQN-ILS (Degroote et al. 2009: the next ``x`` from the least-squares
fit of the last 8 residual differences), to ``|x~ - x| <= tol |x~|``.
Its adjoint runs the sweeps of :class:`adjoint.Adjoint` in reverse (``x``, then ``u``, then
``w``), the backward edge ``y = F_x^T lam_w + S_x^T lam_u`` into the mover solved by GMRES on
the replicated ``(2n,)`` fixed point ``y = T(y)`` (one sweep per iteration), then

    df/drho = g_rho + D_rho^T lam_x + S_rho^T lam_u + F_rho^T lam_w.

Compliance ``c = f . u`` has the partials ``g_u = f``, ``g_w = f_w^T u``, ``g_x = f_x^T u``,
``g_rho = f_rho^T u``; ``S = K_s u - f`` so ``S_w = -f_w``, ``S_x = -f_x``.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse.linalg as spla

from tofsi.core.blocks import State
from tofsi.core.errors import InputError, NumericalError
from tofsi.optimization.problem import mesh_quality
from tofsi.optimization.protocol import Evaluation
from tofsi.parallel.flow_problem import DistributedFlowProblem
from tofsi.parallel.slab_flow import SlabCoupling
from tofsi.parallel.slab_increments import SlabIncrementMover
from tofsi.parallel.slab_mover import SlabMover
from tofsi.parallel.slab_structure import SlabStructure

log = logging.getLogger(__name__)
HISTORY = 8          # IQN-ILS: the residual differences kept
ADJOINT_RTOL = 1e-13  # the flow's transposed solve: at 1e-11 the gradient was off by 2e-8 (the Brinkman
                      # solid makes J_c ill-conditioned), at 1e-13 by 2e-9 (headline scene, 20 x 10)


def check(scene) -> None:
    """Refuse, before anything is built, an FSI scene the distributed problem cannot optimize."""
    e, st, d = scene.effects, scene.structure, scene.design
    materials = {st.model, *d.structure_model}
    if materials != {"linear"}:
        raise InputError("structure.model", sorted(materials), "linear (small strain) for the distributed "
                         "FSI problem under mpiexec; finite strain runs serially, or with "
                         "solver.linear_solver = 'petsc' (every rank the serial problem, MUMPS across them)")
    if d.objective != "compliance":
        raise InputError("design.objective", d.objective, "compliance for the distributed FSI problem")
    if st.density > 0 and any(st.gravity):
        raise InputError("structure.gravity", list(st.gravity), "no weight for the distributed FSI problem")
    if e.coupling == "two-way" and e.mesh_motion != "none" and d.min_skewness > -1.0:
        raise InputError("design.min_skewness", d.min_skewness, "-1 (no mesh-quality constraint) for the "
                         "distributed FSI problem")


def problem_class(scene):
    """The distributed problem of ``scene``: the flow alone, or with a structure."""
    return DistributedFlowProblem if scene.effects.structure == "none" else DistributedFsiProblem


class DistributedFsiProblem(DistributedFlowProblem):
    """The compliance design problem of an FSI ``scene``, its flow by slabs on the ranks of ``comm``."""

    refuse = staticmethod(check)

    def prepare(self) -> None:
        model = self.model
        self.coupling = SlabCoupling(self.engine, model.structure)
        self.structure = SlabStructure(model.structure, self.engine)
        motion = getattr(model, "motion", None)              # the mover by slabs
        mover = None if motion is None else SlabIncrementMover if motion.path_dependent else SlabMover
        self.mover = None if mover is None else mover(motion, self.coupling)
        self.x: np.ndarray | None = None               # the last converged mesh motion (the next start)
        self.tol = min(self.scene.coupled.tol, 1e-10)
        self.max_iter = self.scene.coupled.max_iter

    def set_guess(self, state: State | None) -> None:
        super().set_guess(state)
        if state is not None:
            self.x = state.fields.get("x")

    # ---- the forward solve ---------------------------------------------------------------------
    def _flow(self, X, rho, params, first: bool) -> tuple[np.ndarray, dict]:
        guess, self.guess = (self.guess, None) if first else (None, None)
        try:
            report = self.engine.solve(X, rho, params, w0=guess, warm=self.warm and guess is None)
        except NumericalError:
            self.warm = False
            raise
        self.warm = True
        return self.coupling.whole(self.engine.w), report

    def _structure(self, w, X, rho, params):
        """The load and ``u = K_s^-1 f`` (the structure by slabs, its MUMPS factors kept)."""
        f = self.coupling.load(w, X, rho, params)
        return f, self.structure.solve(f)

    def solve(self, rho, params, system) -> dict:
        """The coupled state at ``rho``: ``{"w", "u", "x", "f", "lin_x", "reports"}``
        (``w`` whole-length with the slab's entries; ``x``, ``lin_x`` None one-way)."""
        self.structure.factorize(rho, self.model.structure.simp(params))
        if "x" not in system.names:
            w, report = self._flow(None, rho, params, True)
            f, u = self._structure(w, None, rho, params)
            return {"w": w, "u": u, "x": None, "f": f, "lin_x": None, "reports": {"w": report}}
        x = np.zeros(system.by_name["x"].size) if self.x is None else np.array(self.x, dtype=float)
        lin_x, dR, dX, history = None, [], [], []
        previous = None
        for it in range(self.max_iter):
            X = x.reshape(-1, 2)
            w, report = self._flow(X, rho, params, it == 0)
            f, u = self._structure(w, X, rho, params)
            x_new, lin_x, moved = self.mover.move(u, rho, guess=x)
            r = x_new - x
            change = float(np.linalg.norm(r)) / max(float(np.linalg.norm(x_new)), 1e-300)
            history.append(change)
            log.info("distributed two-way sweep %d: |x~ - x|/|x~| = %.3e (flow Newton %d, mover Newton %d)", it,
                     change, report["newton_iterations"], moved["newton_iterations"])
            if not np.isfinite(change):
                raise NumericalError("distributed two-way solve: non-finite mesh motion", {"history": history})
            if change <= self.tol:
                self.model.unfolded(State(rho, {"x": x}))            # a folded mesh is a failure, as serially
                self.x = x
                return {"w": w, "u": u, "x": x, "f": f, "lin_x": lin_x,
                        "reports": {"w": report, "mover": moved,
                                    "coupled": {"sweeps": it + 1, "history": history}}}
            if previous is not None:                                    # IQN-ILS
                dR.append(r - previous[0])
                dX.append(x_new - previous[1])
                del dR[:-HISTORY], dX[:-HISTORY]
            previous = (r, x_new)
            if dR:
                c = np.linalg.lstsq(np.column_stack(dR), -r, rcond=None)[0]
                x = x_new + np.column_stack(dX) @ c
            else:
                x = x + 0.5 * r
        raise NumericalError(f"distributed two-way solve: no convergence in {self.max_iter} sweeps",
                             {"history": history})

    # ---- the adjoint ---------------------------------------------------------------------------
    def gradient(self, s, rho, params) -> tuple[float, np.ndarray]:
        """Compliance and ``dc/drho`` (E,) at the state ``s`` of :meth:`solve`, the same on every rank."""
        cp, eng, st = self.coupling, self.engine, self.model.structure
        w, u, f = s["w"], s["u"], s["f"]
        X = None if s["x"] is None else s["x"].reshape(-1, 2)
        lin_x = s["lin_x"]
        g_w = cp.load_fluid_transpose(w, X, rho, params, u)                       # distributed
        g_x = None if X is None else cp.load_shape_transpose(w, X, rho, params, u)
        total = cp.load_density(w, X, rho, params, u)                           # g_rho
        material = self.model.system_for(self.stage).by_name["u"].material

        def sweep(y):
            """One reverse sweep with the backward edge ``y`` into the mover: the multipliers'
            parts and the next ``y``."""
            out = {}
            u_bar = f
            if lin_x is not None:
                out["lam_x"] = lin_x.solve_transpose(-(g_x + y))
                bars, out["rho_x"] = lin_x.transpose_partials(out["lam_x"])
                u_bar = f + bars["u"]
            lam_u = self.structure.solve_transpose(-u_bar)                        # zero on the clamped dofs
            out["lam_u"] = lam_u
            b = cp.load_fluid_transpose(w, X, rho, params, lam_u)
            b.aypx(-1.0, g_w)                                                    # g_w - f_w^T lam_u
            b.scale(-1.0)
            lam_w = eng.solve_transpose(b, rtol=ADJOINT_RTOL)
            out["lam_w"] = cp.whole(lam_w)
            b.destroy()
            lam_w.destroy()
            if lin_x is not None:
                out["y"] = (cp.flow_shape_transpose(w, X, rho, params, out["lam_w"])
                            - cp.load_shape_transpose(w, X, rho, params, lam_u))
            return out

        parts = sweep(None if lin_x is None else np.zeros(s["x"].size))
        if lin_x is not None:
            c0 = parts["y"]
            if np.any(c0):
                operator = spla.LinearOperator((c0.size,) * 2, matvec=lambda v: v - (sweep(v)["y"] - c0))
                y, info = spla.gmres(operator, c0, rtol=1e-12, atol=0.0, restart=50, maxiter=2)
                parts = sweep(y)
                residual = float(np.linalg.norm(parts["y"] - y)) / max(float(np.linalg.norm(c0)), 1e-300)
                log.info("distributed two-way adjoint: GMRES info %d, |T(y) - y|/|c| = %.2e", info, residual)
                if not np.all(np.isfinite(y)) or residual > 1e-8:
                    raise NumericalError("distributed two-way adjoint did not converge",
                                         {"relative_residual": residual})
            if parts.get("rho_x") is not None:
                total = total + parts["rho_x"]
        eng.release_transpose()
        lam_u = parts["lam_u"]
        internal = material.density_vectors(u, rho, st.simp(params))              # (E, 8), replicated
        total = (total + np.einsum("ea,ea->e", internal, lam_u[st.dofs])
                 - cp.load_density(w, X, rho, params, lam_u)
                 + cp.flow_density(w, X, rho, params, parts["lam_w"]))
        return float(f @ u), total

    # ---- one evaluation ---------------------------------------------------------------------------
    def _new_evaluation(self, gamma: np.ndarray) -> Evaluation:
        params, stage = self.params, self.stage
        rho = self.serial.densities(gamma)
        system = self.model.system_for(stage)
        s = self.solve(rho, params, system)
        self.evaluations += 1
        f, d_rho = self.gradient(s, rho, params)
        df = self.map.transpose(gamma, params.beta, d_rho)
        g, dg, solid = self.volume_bound(gamma, rho)
        w = self.engine.gather()                                                   # rank 0 only
        fields = {"w": w, "u": s["u"]} if s["x"] is None else {"w": w, "u": s["u"], "x": s["x"]}
        state = State(rho, fields, params, True, s["reports"], stage=stage)
        quality = mesh_quality(self.model, state)
        log.info("distributed FSI evaluation %d: f = %.10g", self.evaluations, f)
        return Evaluation(gamma, f, df, g, dg, solid, quality, state=state if w is not None else None)
