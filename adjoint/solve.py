"""One block adjoint solve per quantity, and the total derivative with respect to rho.

With the fields' Jacobian ``J`` in the order (u, x, w) (see ``docs/design.md``)

    J^T lam = -(df/du, df/dx, df/dw),    df/drho = df/drho|_partial + lam^T dR/drho,

solved the way the forward problem allows:

* one-way (no mesh motion): ``S_u^T lam_u = -f_u``, then
  ``F_w^T lam_w = -(f_w + S_w^T lam_u)`` -- two solves with the forward
  factorizations (the structure's LU; the flow's last Newton LU preconditions
  GMRES on the converged Jacobian);
* monolithic (a mover with a residual form): ``J^T lam = -f`` with the
  forward Newton's factorization preconditioning GMRES;
* block Gauss-Seidel (any mover, also path-dependent ones, with only a
  vector-Jacobian product ``x = Phi(u, rho)``): repeat
  ``lam_w = -F_w^-T (f_w + S_w^T lam_u)``, ``xbar = f_x + S_x^T lam_u + F_x^T lam_w``,
  ``ubar = Phi_u^T xbar``, ``lam_u = -S_u^-T (f_u + ubar)`` until ``lam_u``
  settles (with Aitken relaxation), then
  ``df/drho = f_rho + S_rho^T lam_u + F_rho^T lam_w + Phi_rho^T xbar``.

Boundary conditions are the forward ones made homogeneous, applied by the
same Dirichlet operators. A quantity that depends on rho alone (the volume)
needs no solve. The adjoint refuses a state the forward solve did not report
as converged.
"""

from __future__ import annotations

import numpy as np

from adjoint.blocks import Blocks
from tofsi.errors import NumericalError


class Adjoint:
    """Adjoint gradients of any number of quantities at one converged coupled state."""

    def __init__(self, model, state, tol: float = 1e-11, max_iter: int = 100):
        if not getattr(state, "converged", False):
            raise NumericalError("adjoint refused: the forward state is not converged", {})
        self.model, self.state = model, state
        self.blocks = Blocks(model, state)
        self.tol, self.max_iter = tol, max_iter
        self.reports: list[dict] = []

    def method(self) -> str:
        m = self.model
        if not m.two_way:
            return "one-way"
        if m.settings.method == "monolithic" and m.motion.has_residual:
            return "monolithic"
        return "block Gauss-Seidel"

    def gradient(self, quantity, partials: dict | None = None) -> np.ndarray:
        """``d quantity / d rho`` (E,): partials plus the adjoint term."""
        g = quantity.partials(self.model, self.state) if partials is None else partials
        total = np.array(g.get("rho", np.zeros(self.model.mesh.n_elements)), dtype=float)
        if not any(k in g for k in ("u", "x", "w")):
            return total
        method = self.method()
        if method == "one-way":
            total += self._one_way(g)
        elif method == "monolithic":
            total += self._monolithic(g)
        else:
            total += self._gauss_seidel(g)
        return total

    # ---- strategies ---------------------------------------------------------------------
    def _solve_u(self, rhs):
        st = self.model.structure
        return st.solver(self.state.rho).solve_transpose(st.bc.homogenize(rhs))

    def _solve_w(self, rhs):
        fl = self.model.flow
        return fl.solver.solve_transpose(self.blocks.F_w(), fl.bc.homogenize(rhs))

    def _fluid_part(self, g, lam_u):
        b = self.blocks
        rhs = -np.asarray(g.get("w", 0.0)) * np.ones(self.model.flow.size)
        if lam_u is not None:
            rhs = rhs - b.S_w().T @ lam_u
        lam_w = self._solve_w(rhs)
        return lam_w, b.F_rho().T @ lam_w

    def _one_way(self, g) -> np.ndarray:
        lam_u, extra = None, 0.0
        if self.model.structure is not None and "u" in g:
            lam_u = self._solve_u(-np.asarray(g["u"]))
            extra = self.blocks.S_rho().T @ lam_u
        lam_w, from_flow = self._fluid_part(g, lam_u)
        self.reports.append({"method": "one-way"})
        return extra + from_flow

    def _monolithic(self, g) -> np.ndarray:
        m, s, b = self.model, self.state, self.blocks
        n2 = 2 * m.mesh.n_nodes
        rhs = np.zeros(2 * n2 + m.flow.size)
        rhs[:n2] = -m.structure.bc.homogenize(np.asarray(g.get("u", 0.0)) * np.ones(n2))
        rhs[n2:2 * n2] = -np.asarray(g.get("x", 0.0)) * np.ones(n2)
        rhs[2 * n2:] = -m.flow.bc.homogenize(np.asarray(g.get("w", 0.0)) * np.ones(m.flow.size))
        J = self._get_jacobian()
        lam = m._newton_solver.solve_transpose(J, rhs)
        lam_u, lam_x, lam_w = m.split(lam)
        _, from_mesh = m.motion.partials_transpose(s.x, s.u, s.rho, lam_x)
        self.reports.append({"method": "monolithic"})
        return b.S_rho().T @ lam_u + from_mesh + b.F_rho().T @ lam_w

    def _get_jacobian(self):
        if "J" not in self.blocks._cache:
            m, s = self.model, self.state
            self.blocks._cache["J"] = m.jacobian(s.u, s.x, s.w, s.rho, Fw=self.blocks.F_w())
        return self.blocks._cache["J"]

    def _gauss_seidel(self, g) -> np.ndarray:
        m, s, b = self.model, self.state, self.blocks
        n2 = 2 * m.mesh.n_nodes
        g_u = np.asarray(g.get("u", 0.0)) * np.ones(n2)
        g_x = np.asarray(g.get("x", 0.0)) * np.ones(n2)
        lam_u = self._solve_u(-g_u)
        omega, r_prev, history = 1.0, None, []
        for it in range(self.max_iter):
            lam_w, _ = self._fluid_part(g, lam_u)
            xbar = g_x + b.S_x().T @ lam_u + b.F_x().T @ lam_w
            ubar, rho_mesh = m.motion.vjp(s.motion_result, xbar.reshape(-1, 2), s.rho)
            new = self._solve_u(-(g_u + ubar))
            r = new - lam_u
            change = np.linalg.norm(r) / max(np.linalg.norm(new), 1e-300)
            history.append(change)
            if change <= self.tol:
                lam_u = new
                lam_w, from_flow = self._fluid_part(g, lam_u)
                xbar = g_x + b.S_x().T @ lam_u + b.F_x().T @ lam_w
                _, rho_mesh = m.motion.vjp(s.motion_result, xbar.reshape(-1, 2), s.rho)
                self.reports.append({"method": "block Gauss-Seidel", "history": history})
                return b.S_rho().T @ lam_u + from_flow + rho_mesh
            if r_prev is not None:
                dr = r - r_prev
                omega = -omega * float(r_prev @ dr) / max(float(dr @ dr), 1e-300)
            lam_u = lam_u + omega * r
            r_prev = r
        raise NumericalError(f"adjoint block Gauss-Seidel did not converge in {self.max_iter} sweeps",
                             {"history": history})
