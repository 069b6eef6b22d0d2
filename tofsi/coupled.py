"""The coupled fluid-structure-mesh problem: only the fields a scene's effects ask for.

Fields ``u`` (structure, 2n), ``x`` (mesh motion, 2n) and ``w`` (flow) with
residuals ``S``, ``D``, ``F`` (see ``docs/design.md``). The scene's effects
decide what exists: no fluid -> no ``w``; no structure -> no ``u``; one-way
coupling or no mesh motion -> no ``x`` (the flow sees the reference mesh and
the mover is never called).

Two-way coupling is solved either

* partitioned: ``w = F^-1(x)``, ``u~ = S^-1(w, x)``, relax ``u += omega (u~ - u)``
  with Aitken's ``omega``, ``x = Phi(u)`` (the mover), until
  ``|u~ - u| <= tol |u|``; or
* monolithic: Newton on the assembled 3x3 block Jacobian

      | S_u  S_x  S_w |
      | D_u  D_x   0  |
      |  0   F_x  F_w |

  (a mover with a residual form), with a line search on the block-scaled
  residual. Both report their history and raise
  :class:`~tofsi.errors.NumericalError` when they do not converge.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from tofsi.channel import build_mesh
from tofsi.errors import InputError, NumericalError
from tofsi.linalg import DirectSolver, RecyclingSolver, nested_dissection
from tofsi.mesh import DESIGN, SOLID
from tofsi.physics.flow import Flow
from tofsi.physics.motion_block import MeshMotion
from tofsi.physics.structure import Structure
from tofsi.threads import configure as configure_linear_algebra

log = logging.getLogger(__name__)


@dataclass
class State:
    """A solved coupled state; absent fields are None."""

    rho: np.ndarray
    w: np.ndarray | None = None
    u: np.ndarray | None = None
    x: np.ndarray | None = None
    converged: bool = False
    reports: dict = field(default_factory=dict)
    motion_result: object = None          # the mover's result (for its adjoint)

    @property
    def displacement(self) -> np.ndarray | None:
        """Mesh displacement ``(n, 2)`` the flow was solved on (None: reference mesh)."""
        return None if self.x is None else self.x.reshape(-1, 2)


class CoupledModel:
    """Fields, blocks and solvers of a scene (with its design densities)."""

    def __init__(self, scene, mesh=None):
        self.scene = scene
        configure_linear_algebra(scene.solver)             # backend and threads ([solver])
        self.mesh = build_mesh(scene.geometry, scene.mesh) if mesh is None else mesh
        e = scene.effects
        self.flow = None if e.fluid == "none" else Flow(self.mesh, scene.fluid, stokes=e.fluid == "stokes")
        self.structure = None
        if e.structure != "none":
            if self.flow is None:
                raise InputError("effects.structure", e.structure,
                                 "the structure is loaded by the flow; set effects.fluid too")
            self.structure = Structure(self.mesh, scene.structure, self.flow)
        self.two_way = (e.coupling == "two-way" and e.mesh_motion != "none"
                        and self.structure is not None)
        self.motion = MeshMotion(self.mesh, scene) if self.two_way else None
        self.settings = scene.coupled
        if self.two_way and self.settings.method == "monolithic" and not self.motion.has_residual:
            raise InputError("coupled.method", "monolithic",
                             f"the {scene.mover.name} mover with these settings is path-dependent "
                             "(increments on the updated mesh); use 'partitioned'")
        self._newton_solver = None

    # ---- densities -----------------------------------------------------------------
    @property
    def design_elements(self) -> np.ndarray:
        return np.flatnonzero(self.mesh.region == DESIGN)

    def densities(self, rho_design=None) -> np.ndarray:
        """Element densities: 1 in fixed solid, 0 in fixed fluid, ``rho_design`` in the design region."""
        rho = (self.mesh.region == SOLID).astype(float)
        design = self.design_elements
        if design.size:
            rho[design] = self.scene.design.volume_fraction if rho_design is None else rho_design
        return rho

    # ---- forward solve -------------------------------------------------------------------
    def solve(self, rho: np.ndarray, guess: State | None = None, progress=None) -> State:
        """The coupled state for densities ``rho`` (E,); ``guess`` warm-starts the solvers."""
        t0 = time.perf_counter()
        if self.flow is None:
            raise InputError("effects.fluid", "none", "nothing to solve: the scene has no flow")
        if not self.two_way:
            state = self._one_way(rho, guess)
        elif self.settings.method == "monolithic":
            state = self._monolithic(rho, guess)
        else:
            state = self._partitioned(rho, guess)
        state.reports["wall_time_s"] = time.perf_counter() - t0
        state.converged = True
        return state

    def _one_way(self, rho, guess) -> State:
        w, frep = self.flow.solve(None, rho, None if guess is None else guess.w)
        state = State(rho=rho, w=w, reports={"flow": frep.as_dict()})
        if self.structure is not None:
            state.u = self.structure.solve(w, None, rho)
        return state

    def _partitioned(self, rho, guess) -> State:
        s = self.settings
        u = np.zeros(self.structure.size) if guess is None or guess.u is None else guess.u.copy()
        x = np.zeros(2 * self.mesh.n_nodes) if guess is None or guess.x is None else guess.x.copy()
        w = None if guess is None else guess.w
        omega, r_prev, history, result = s.relaxation, None, [], None
        for k in range(s.max_iter):
            w, frep = self.flow.solve(x.reshape(-1, 2), rho, w)
            u_new = self.structure.solve(w, x.reshape(-1, 2), rho)
            r = u_new - u
            if r_prev is not None:
                dr = r - r_prev
                omega = -omega * float(r_prev @ dr) / max(float(dr @ dr), 1e-300)
            change = np.linalg.norm(r) / max(np.linalg.norm(u_new), 1e-300)
            history.append({"iteration": k, "relative_change": change, "omega": omega})
            if change <= s.tol:
                u = u_new
                x_arr, result = self.motion.solve(u, rho)
                x = x_arr.ravel()
                return State(rho=rho, w=self.flow.solve(x.reshape(-1, 2), rho, w)[0], u=u, x=x,
                             motion_result=result,
                             reports={"coupling": {"method": "partitioned", "history": history},
                                      "flow": frep.as_dict(), "mover": result.report.as_dict()})
            u = u + omega * r
            r_prev = r
            x_arr, result = self.motion.solve(u, rho)
            x = x_arr.ravel()
        raise NumericalError(f"partitioned coupling did not converge in {s.max_iter} iterations",
                             {"history": history})

    # ---- residuals and the block Jacobian -------------------------------------------
    def split(self, z: np.ndarray):
        n2 = 2 * self.mesh.n_nodes
        return z[:n2], z[n2:2 * n2], z[2 * n2:]

    def residual_blocks(self, u, x, w, rho):
        """``(S, D, F)`` with the Dirichlet rows as ``(value - prescribed)``, and ``D_x``, ``F_w``."""
        X = x.reshape(-1, 2)
        S = self.structure.bc.homogenize(self.structure.residual(u, w, X, rho))
        S[self.structure.bc.fixed] = u[self.structure.bc.fixed]
        D, Dx = self.motion.residual(x, u, rho)
        Fw, F, _ = self.flow.jacobian(w, X, rho)
        F = self.flow.bc.homogenize(F)
        F[self.flow.bc.fixed] = (w - self.flow.values)[self.flow.bc.fixed]
        return (S, D, F), Dx, Fw

    def jacobian(self, u, x, w, rho, Dx=None, Fw=None) -> sp.csr_matrix:
        """The 3x3 block Jacobian in the order (u, x, w)."""
        X = x.reshape(-1, 2)
        if Dx is None:
            _, Dx = self.motion.residual(x, u, rho)
        if Fw is None:
            Fw = self.flow.jacobian(w, X, rho)[0]
        st, fl = self.structure, self.flow
        Su = st.stiffness(rho)
        Sx = st.bc.free_rows(st.shape_partial(w, X, rho))
        Sw = st.bc.free_rows(st.fluid_partial(X, rho))
        Du = self.motion.structure_partial(rho)
        Fx = fl.bc.free_rows(fl.shape_partial(w, X, rho))
        return sp.bmat([[Su, Sx, Sw], [Du, Dx, None], [None, Fx, Fw]], format="csr")

    def _monolithic_perm(self):
        m = self.mesh
        i = np.tile(np.arange(m.nx + 1), m.ny + 1)
        j = np.repeat(np.arange(m.ny + 1), m.nx + 1)
        q1 = np.repeat(np.column_stack([2 * i, 2 * j]), 2, axis=0)
        grid = np.vstack([q1, q1, self.flow.grid()])
        last = np.zeros(len(grid), bool)
        last[2 * q1.shape[0] + self.flow.n_velocity:] = True
        return nested_dissection(grid, last=last)

    def _monolithic(self, rho, guess) -> State:
        s = self.settings
        if guess is None or guess.x is None:
            guess = self._one_way(rho, guess)             # start from the one-way state
            x0, _ = self.motion.solve(guess.u, rho)
            guess.x = x0.ravel()
        u, x, w = guess.u.copy(), guess.x.copy(), guess.w.copy()
        if self._newton_solver is None:
            perm = self._monolithic_perm()
            self._newton_solver = RecyclingSolver(lambda A: DirectSolver(A, perm=perm))
        scales = None
        history = []
        for it in range(s.max_iter + 1):
            (S, D, F), Dx, Fw = self.residual_blocks(u, x, w, rho)
            if scales is None:
                load = self.structure.load(w, x.reshape(-1, 2), rho)
                scales = (max(np.linalg.norm(load), 1e-300),
                          max(np.linalg.norm(D), np.linalg.norm(Dx @ x), 1e-300),
                          max(np.linalg.norm(self.flow.bc.homogenize(
                              self.flow.residual(self.flow.initial(), x.reshape(-1, 2), rho))), 1e-300))
            norms = [np.linalg.norm(r) / sc for r, sc in zip((S, D, F), scales)]
            history.append({"iteration": it, "S": norms[0], "D": norms[1], "F": norms[2]})
            if max(norms) <= s.tol:
                return State(rho=rho, w=w, u=u, x=x, reports={
                    "coupling": {"method": "monolithic", "history": history}})
            if it == s.max_iter:
                break
            J = self.jacobian(u, x, w, rho, Dx, Fw)
            R = np.concatenate([S, D, F])
            dz = self._newton_solver.solve(J, -R)
            merit = max(norms)
            for alpha in 0.5 ** np.arange(8):
                du, dx, dw = self.split(alpha * dz)
                try:
                    (S2, D2, F2), _, _ = self.residual_blocks(u + du, x + dx, w + dw, rho)
                except NumericalError:
                    continue
                trial = max(np.linalg.norm(r) / sc for r, sc in zip((S2, D2, F2), scales))
                if np.isfinite(trial) and trial < (1 - 1e-4 * alpha) * merit:
                    break
            else:
                raise NumericalError("monolithic coupling: line search found no decrease",
                                     {"history": history})
            u, x, w = u + du, x + dx, w + dw
        raise NumericalError(f"monolithic coupling did not converge in {s.max_iter} Newton iterations",
                             {"history": history})

    # ---- figures --------------------------------------------------------------------------
    def figures(self, state: State) -> dict:
        """Flow and structure figures of a state (pressure drop, drag, compliance, ...)."""
        out = {}
        X = state.displacement
        if self.flow is not None and state.w is not None:
            out.update(self.flow.figures(state.w, X, state.rho))
        if self.structure is not None and state.u is not None:
            out.update(self.structure.figures(state.u, state.w, X, state.rho))
        return out
