"""Adjoint gradients over a block system: one adjoint solve per quantity, any blocks.

For fields ``z_b`` with residuals ``R_b`` (see :mod:`tofsi.core.blocks`) and a
quantity ``f(z, rho)`` with partials ``g_b = df/dz_b``, the multipliers solve

    (dR_b/dz_b)^T lam_b = -(g_b + sum_{c uses b} (dR_c/dz_b)^T lam_c),
    df/drho = df/drho|_partial + sum_b (dR_b/drho)^T lam_b.

The system's dependency components are visited in reverse order:

* a single block: one transposed solve with its forward factorization
  (one-way coupling: the structure, then the flow);
* a cycle that the forward solve closed by monolithic Newton: the
  transposed block Jacobian ``J^T lam = -g``, preconditioned by the Newton's
  factorization;
* any other cycle (also with an explicit, path-dependent map, whose
  "solve" is the identity and whose partials are its vector-Jacobian
  product): block Gauss-Seidel sweeps in the reverse of the forward order,
  the relaxed field's multiplier relaxed with Aitken's factor, until its
  relative change is below ``tol``.

The adjoint never names a physics: it reads the blocks' linearizations kept
in the state. It refuses a state the forward solve did not report converged.
"""

from __future__ import annotations

import numpy as np

from tofsi.core.errors import NumericalError
from tofsi.core.iteration import aitken


class Adjoint:
    """Adjoint gradients of any number of quantities at one converged state of a block system."""

    def __init__(self, system, state, tol: float = 1e-11, max_iter: int = 100):
        if not getattr(state, "converged", False):
            raise NumericalError("adjoint refused: the forward state is not converged", {})
        missing = [n for n in system.names if n not in state.linearizations]
        if missing:
            raise NumericalError(f"adjoint refused: the state has no linearization of {missing} "
                                 "(a restored or copied state); solve it again", {})
        self.system, self.state = system, state
        self.tol, self.max_iter = tol, max_iter
        self.reports: list[dict] = []

    def method(self, comp=None) -> str:
        """How the component ``comp`` (default: the last cycle, else the last block) is solved."""
        comps = self.system.components
        comp = comp or (self.system.cycles[-1] if self.system.cycles else comps[-1])
        if len(comp) == 1:
            return "one-way"
        return "monolithic" if tuple(comp) in self.state.coupled else "block Gauss-Seidel"

    def gradient(self, partials: dict) -> np.ndarray:
        """``d quantity / d rho`` (E,) from the quantity's partials ``{field: df/dz, "rho": df/drho}``."""
        lins = self.state.linearizations
        total = np.array(partials.get("rho", np.zeros(len(self.state.rho))), dtype=float)
        bars = {n: np.zeros(self.system.by_name[n].size) for n in self.system.names}
        given = False
        for n in self.system.names:
            g = partials.get(n)
            if g is not None:
                bars[n] = bars[n] + np.asarray(g, dtype=float) * np.ones(bars[n].size)
                given = given or bool(np.any(g))
        if not given:
            return total                                  # depends on rho alone: no solve
        for comp in reversed(self.system.components):
            method = self.method(comp)
            if method == "one-way":
                lam = {comp[0]: lins[comp[0]].solve_transpose(-bars[comp[0]])}
            elif method == "monolithic":
                lam = self._monolithic(comp, bars)
            else:
                lam = self._gauss_seidel(comp, bars)
            self.reports.append({"method": method, "fields": list(comp)})
            for name in comp:                              # to the fields upstream, and to rho
                inputs, rho_bar = lins[name].transpose_partials(lam[name])
                for other, bar in inputs.items():
                    if other not in comp:
                        bars[other] = bars[other] + bar
                if rho_bar is not None:
                    total += rho_bar
        return total

    def _monolithic(self, comp, bars) -> dict:
        coupled = self.state.coupled[tuple(comp)]
        lam = coupled.solve_transpose(-np.concatenate([bars[n] for n in comp]))
        return self.system.split(lam, comp)

    def _gauss_seidel(self, comp, bars) -> dict:
        lins = self.state.linearizations
        relax = self.system.relaxed_field(comp)
        sweep = tuple(reversed(comp))
        lam = {n: np.zeros(self.system.by_name[n].size) for n in comp}
        into = {n: {} for n in comp}                       # into[b][c] = (dR_c/dz_b)^T lam_c
        omega, r_previous, history = 1.0, None, []
        for it in range(self.max_iter):
            change = 0.0
            for b in sweep:
                rhs = bars[b] + sum(into[b].values(), np.zeros(bars[b].size))
                new = lins[b].solve_transpose(-rhs)
                if b == relax:
                    r = new - lam[b]
                    change = float(np.linalg.norm(r) / max(np.linalg.norm(new), 1e-300))
                    omega = aitken(omega, r, r_previous)
                    new = new if it == 0 else lam[b] + omega * r
                    r_previous = r if it > 0 else None
                lam[b] = new
                inputs, _ = lins[b].transpose_partials(new)
                for other, bar in inputs.items():
                    if other in comp:
                        into[other][b] = bar
            history.append(change)
            if it > 0 and change <= self.tol:
                self.reports.append({"method": "block Gauss-Seidel", "history": history})
                return lam
        raise NumericalError(f"adjoint block Gauss-Seidel did not converge in {self.max_iter} sweeps",
                             {"history": history})
