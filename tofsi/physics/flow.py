"""The fluid block F(w; x, rho): Taylor-Hood flow in the channel on the moved mesh.

``w = (v, p)``: velocity on the Q2 nodes (dofs ``2 k + i``), then pressure on
the Q1 corners (dofs ``2 n9 + k``). The mesh is the reference mesh moved by
``x`` (n, 2) -- the ALE configuration -- and Brinkman friction
``alpha(rho_e)`` acts per element. Boundary conditions come from
:mod:`tofsi.physics.flow_boundary` (walls, parabolic inflow and outflow, open
outlets on any side; by default inflow on the left and an open right side),
where open segments take the natural condition of the viscous form
(``zero-pressure``: the do-nothing condition of the gradient form,
``traction-free``: ``sigma n = 0``). With no open boundary the pressure is
pinned at one corner.

Steady Navier-Stokes is solved by Newton's method with a backtracking line
search on ``|R|``; when it fails, by continuation in the fluid density
(Reynolds number) from Stokes flow. Every solve reports its history and
raises :class:`~tofsi.errors.NumericalError` rather than return an
unconverged state.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.sparse as sp

from tofsi.errors import NumericalError
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.interpolation import Brinkman
from tofsi.linalg import DirectSolver, RecyclingSolver, nested_dissection
from tofsi.fem.geometry import map_points, physical_gradients
from tofsi.physics.flow_boundary import FlowBoundary
from tofsi.physics.fluid_kernel import (N2, POINTS, WEIGHTS, brinkman_partial, fluid_element,
                                        velocity_fields)

log = logging.getLogger(__name__)
COMPLEX_STEP = 1e-30
ROUND_OFF = 64 * np.finfo(float).eps        # componentwise backward error that counts as exact


@dataclass
class FlowReport:
    converged: bool = False
    newton_iterations: int = 0
    residual_history: list = field(default_factory=list)
    continuation: list = field(default_factory=list)      # densities used when continuing
    wall_time_s: float = 0.0

    def as_dict(self) -> dict:
        return asdict(self)


class Flow:
    """Taylor-Hood discretization of the channel flow on a structured mesh.

    mesh : StructuredQuadMesh; settings : FluidSettings; stokes : drop inertia
    boundary_velocity : optional ``v(points (m, 2)) -> (m, 2)`` prescribed on all four
        sides instead of the channel conditions (closed box; verification problems)
    body_force : optional ``f(points (E, G, 2)) -> (E, G, 2)`` [N/m^3] on the current
        configuration (complex-safe, so shape derivatives include it)
    """

    def __init__(self, mesh, settings, stokes: bool = False, boundary_velocity=None,
                 body_force=None):
        self.mesh, self.settings = mesh, settings
        self.body_force = body_force
        self.density = 0.0 if stokes else settings.density
        self.symmetric = settings.outlet == "traction-free"
        self.brinkman = Brinkman(settings.alpha_max, settings.alpha_min, settings.brinkman_q)
        n9, n = mesh.n_nodes9, mesh.n_nodes
        self.n_velocity, self.size = 2 * n9, 2 * n9 + n
        self.dofs = np.hstack([element_dofs(mesh.quads9, 2), 2 * n9 + mesh.quads])   # (E, 22)
        self.boundary = (FlowBoundary.for_channel(mesh, settings) if boundary_velocity is None
                         else FlowBoundary.prescribed(mesh, boundary_velocity))
        self.open_outlet = self.boundary.is_open
        fixed = [self.boundary.fixed] + ([] if self.open_outlet else [np.array([2 * n9])])  # closed: pin p
        self.values = np.zeros(self.size)
        self.values[:2 * n9] = self.boundary.values
        self.bc = DirichletOperator(self.dofs, self.dofs, self.size, np.concatenate(fixed))
        self.solver = RecyclingSolver(self._factorize)
        self._perm = None

    # ---- geometry and state -------------------------------------------------------
    def corners(self, x=None) -> np.ndarray:
        """Current corner coordinates ``(E, 4, 2)`` of the mesh moved by ``x`` (n, 2)."""
        P = self.mesh.points if x is None else self.mesh.points + x
        return P[self.mesh.quads]

    def split(self, w):
        """Element velocities ``(E, 9, 2)`` and pressures ``(E, 4)``."""
        we = w[self.dofs]
        return we[:, :18].reshape(-1, 9, 2), we[:, 18:]

    def alpha(self, rho) -> np.ndarray:
        """Brinkman friction per element; ``rho = None`` means all fluid."""
        return self.brinkman(np.zeros(self.mesh.n_elements) if rho is None else rho)

    def initial(self) -> np.ndarray:
        """The state with the boundary values and zero elsewhere."""
        return self.values.copy()

    # ---- residual, Jacobian, partials ---------------------------------------------
    def element_residual(self, w, x, rho, jacobian=True, density=None, Xe=None):
        """Element residuals and Jacobians on the mesh moved by ``x`` (or on corners ``Xe``)."""
        ve, pe = self.split(w)
        Xe = self.corners(x) if Xe is None else Xe
        Re, Ke = fluid_element(Xe, ve, pe, self.alpha(rho),
                               self.density if density is None else density,
                               self.settings.viscosity, self.symmetric, jacobian)
        if self.body_force is not None:
            _, det = physical_gradients(Xe, 1, POINTS)
            f = self.body_force(map_points(Xe, POINTS))                          # (E, G, 2)
            Re = Re.astype(np.result_type(Re, f))
            Re[:, :18] -= np.matmul(N2.T, f * (det * WEIGHTS)[..., None]).reshape(len(Xe), 18)
        return Re, Ke

    def residual(self, w, x=None, rho=None, density=None) -> np.ndarray:
        """``F(w; x, rho)`` (size,), unconstrained (boundary rows included)."""
        Re, _ = self.element_residual(w, x, rho, jacobian=False, density=density)
        return assemble_vector(self.dofs, Re, self.size)

    def jacobian(self, w, x=None, rho=None, density=None):
        """``F_w`` as the constrained CSR matrix (identity on fixed dofs) and ``F``."""
        Re, Ke = self.element_residual(w, x, rho, density=density)
        return self.bc.matrix(Ke), assemble_vector(self.dofs, Re, self.size), Ke

    def shape_partial(self, w, x=None, rho=None) -> sp.csr_matrix:
        """``F_x`` (size x 2n): derivative with respect to the mesh displacement (complex step)."""
        Xe = self.corners(x)
        E = Xe.shape[0]
        cols = element_dofs(self.mesh.quads, 2)                 # (E, 8) coordinate dofs
        vals = np.empty((E, 22, 8))
        for j in range(8):
            Xc = Xe.astype(complex)
            Xc[:, j // 2, j % 2] += 1j * COMPLEX_STEP
            Rc, _ = self.element_residual(w, None, rho, jacobian=False, Xe=Xc)
            vals[:, :, j] = Rc.imag / COMPLEX_STEP
        rows = np.broadcast_to(self.dofs[:, :, None], vals.shape)
        cols = np.broadcast_to(cols[:, None, :], vals.shape)
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())),
                             shape=(self.size, 2 * self.mesh.n_nodes))

    def density_partial(self, w, x, rho) -> sp.csr_matrix:
        """``F_rho`` (size x E): Brinkman friction's derivative per element density."""
        ve, _ = self.split(w)
        rho = np.zeros(self.mesh.n_elements) if rho is None else rho
        vals = brinkman_partial(self.corners(x), ve) * self.brinkman.derivative(rho)[:, None]
        E = vals.shape[0]
        return sp.csr_matrix((vals.ravel(), (self.dofs.ravel(), np.repeat(np.arange(E), 22))),
                             shape=(self.size, E))

    # ---- solving -------------------------------------------------------------------
    def grid(self) -> np.ndarray:
        """Fine-grid positions of the dofs (for the nested-dissection ordering)."""
        m = self.mesh
        I, J = np.meshgrid(np.arange(2 * m.nx + 1), np.arange(2 * m.ny + 1), indexing="xy")
        pos9 = np.empty((m.n_nodes9, 2), dtype=np.int64)
        pos9[m.node9(I.ravel(), J.ravel())] = np.column_stack([I.ravel(), J.ravel()])
        return np.vstack([np.repeat(pos9, 2, axis=0), pos9[: m.n_nodes]])

    def _factorize(self, A):
        if self._perm is None:
            self._perm = nested_dissection(self.grid(), last=np.arange(self.size) >= self.n_velocity)
        return DirectSolver(A, perm=self._perm)

    def solve(self, x=None, rho=None, w0=None, progress=None) -> tuple[np.ndarray, FlowReport]:
        """Steady flow on the mesh moved by ``x`` with densities ``rho``; raises on failure."""
        t0 = time.perf_counter()
        report = FlowReport()
        w = self.initial() if w0 is None else np.where(self.bc.is_fixed, self.values, w0)
        try:
            w = self._newton(w, x, rho, self.density, report)
        except NumericalError as first:
            if self.density == 0.0:
                raise
            log.info("Newton failed at full Reynolds number (%s); continuing from Stokes flow", first)
            w = self._newton(self.initial(), x, rho, 0.0, report)
            steps = self.settings.continuation_steps
            for k in range(1, steps + 1):
                density = self.density * k / steps
                report.continuation.append(density)
                w = self._newton(w, x, rho, density, report)
        report.converged = True
        report.wall_time_s = time.perf_counter() - t0
        return w, report

    def residual_scale(self, x, density) -> float:
        """``|F|`` of the all-fluid state holding only the boundary values: the force scale the
        Newton tolerance is relative to (per mesh position and density; independent of the
        design, so a design's solve never depends on which design came first)."""
        key = (None if x is None else np.asarray(x).tobytes(), density)
        if getattr(self, "_scale", (None,))[0] != key:
            r = np.linalg.norm(self.bc.homogenize(self.residual(self.initial(), x, None, density)))
            self._scale = (key, max(r, 1e-14 * max(1.0, abs(self.settings.inlet_velocity))))
        return self._scale[1]

    @staticmethod
    def backward_error(J, w, r) -> float:
        """Componentwise relative residual ``max_i |r_i| / (|J| |w|)_i``: round-off level
        (~1e-16) means no more digits can be had, whatever the rows' scales (Brinkman rows
        with alpha = 1e9 next to viscous rows of order 1)."""
        size = abs(J) @ np.abs(w)
        floor = 1e-300 + 1e-16 * size.max()
        return float(np.max(np.abs(r) / (size + floor)))

    def _newton(self, w, x, rho, density, report: FlowReport) -> np.ndarray:
        """Newton with inexact (Eisenstat-Walker) solves and a backtracking line search whose
        accepted point's Jacobian is the next iteration's. Converged when ``|F|`` is below
        ``newton_tol`` times the force scale, or when the componentwise backward error has
        reached round-off (``ROUND_OFF``)."""
        s = self.settings
        scale = self.residual_scale(x, density)
        history: list[float] = []
        report.residual_history.append(history)
        J, R, _ = self.jacobian(w, x, rho, density)
        for it in range(s.newton_max_iter + 1):
            r = self.bc.homogenize(R)
            norm = float(np.linalg.norm(r))
            history.append(norm)
            if not np.isfinite(norm):
                raise NumericalError("flow solve: non-finite residual", {"history": history})
            target = s.newton_tol * scale
            if norm <= target or self.backward_error(J, w, r) <= ROUND_OFF:
                self._last = (w, J)
                return w
            if it == s.newton_max_iter:
                break
            eta = 0.1 if len(history) < 2 else min(0.1, 0.9 * (history[-1] / history[-2]) ** 2)
            dw = self.solver.solve(J, -r, rtol=max(eta, 0.1 * target / norm))
            dw[self.bc.fixed] = 0.0
            report.newton_iterations += 1
            for alpha in 0.5 ** np.arange(8):
                trial = w + alpha * dw
                if alpha == 1.0:
                    J_t, R_t, _ = self.jacobian(trial, x, rho, density)
                else:
                    J_t, R_t = None, self.residual(trial, x, rho, density)
                r_t = np.linalg.norm(self.bc.homogenize(R_t))
                if np.isfinite(r_t) and r_t < (1 - 1e-4 * alpha) * norm:
                    break
            else:
                raise NumericalError("flow solve: line search found no decrease",
                                     {"history": history, "density": density})
            w = trial
            J, R = (J_t, R_t) if J_t is not None else self.jacobian(w, x, rho, density)[:2]
        raise NumericalError(f"flow solve: no convergence in {s.newton_max_iter} Newton iterations",
                             {"history": history, "density": density})

    # ---- figures -------------------------------------------------------------------
    def figures(self, w, x=None, rho=None) -> dict:
        """Pressure drop [Pa] and dissipated power [W/m] of a flow state."""
        ve, _ = self.split(w)
        grad, wdet, v, L = velocity_fields(self.corners(x), ve)
        eps = 0.5 * (L + np.swapaxes(L, -1, -2))
        alpha = self.alpha(rho)
        viscous = float(np.sum(2 * self.settings.viscosity * np.einsum("egij,egij->eg", eps, eps) * wdet))
        friction = float(np.sum(alpha[:, None] * np.einsum("egi,egi->eg", v, v) * wdet))
        out = {"dissipated_power": viscous + friction, "viscous_dissipation": viscous,
               "brinkman_dissipation": friction}
        if self.boundary.has_pressure_drop:
            out["pressure_drop"] = float(self.boundary.pressure_drop_weights() @ w[self.n_velocity:])
        return out
