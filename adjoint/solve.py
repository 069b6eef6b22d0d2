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
  written as the linear fixed point they iterate and solved by GMRES to
  ``tol`` (one sweep per iteration).

The adjoint never names a physics: it reads the blocks' linearizations kept
in the state. It refuses a state the forward solve did not report converged.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from tofsi.core.errors import NumericalError

RESTARTS = 4         # GMRES runs of a partitioned cycle's adjoint, each checked against the true residual
FLOOR = 1e-8         # the largest relative residual an adjoint accepts where the sweeps' own solves stop it


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
                lam, partials = self._gauss_seidel(comp, bars)
            self.reports.append({"method": method, "fields": list(comp)})
            for name in comp:                              # to the fields upstream, and to rho
                inputs, rho_bar = (partials[name] if method == "block Gauss-Seidel"
                                   else lins[name].transpose_partials(lam[name]))
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

    def _gauss_seidel(self, comp, bars) -> tuple[dict, dict]:
        """Reverse block Gauss-Seidel over ``comp`` as a linear fixed point, solved by GMRES.

        A sweep in the reverse of the forward order solves each block's transposed system with
        what flows into it from the others: from the blocks before it in the sweep, their
        multipliers of this sweep; from those after it (the backward edges), last sweep's. With
        ``y`` the backward edges' contributions, a sweep is an affine map ``y -> T(y) = G y + c``
        and the multipliers solve ``(I - G) y = c``: GMRES on it, one sweep per iteration (a
        path-dependent mover's sweep is a reverse pass through its increments, so the sweeps are
        what an adjoint costs; GMRES needs as many as the coupling has significant modes, where
        relaxed sweeps crawl, or diverge on a mode the loop amplifies). Returns the multipliers
        and each block's transposed partials at them (from the last sweep).
        """
        lins = self.state.linearizations
        sweep = tuple(reversed(comp))
        order = {n: i for i, n in enumerate(sweep)}
        edges = [(b, c) for c in comp for b in self.system.by_name[c].inputs
                 if b in comp and order[b] < order[c]]          # c's partial feeds b, earlier in the sweep
        sizes = [self.system.by_name[b].size for b, _ in edges]
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(int)

        def run(y):
            into = {n: {} for n in comp}
            for k, (b, c) in enumerate(edges):
                into[b][c] = y[starts[k]:starts[k + 1]]
            lam, partials = {}, {}
            for b in sweep:
                rhs = bars[b] + sum(into[b].values(), np.zeros(bars[b].size))
                lam[b] = lins[b].solve_transpose(-rhs)
                partials[b] = lins[b].transpose_partials(lam[b])
                for other, bar in partials[b][0].items():
                    if other in comp:
                        into[other][b] = bar
            out = np.concatenate([into[b][c] for b, c in edges]) if edges else np.zeros(0)
            return out, lam, partials

        sweeps = [1]
        c0, lam, partials = run(np.zeros(starts[-1]))
        history = []
        if edges and np.any(c0):
            def matvec(v):
                sweeps[0] += 1
                return v - (run(v)[0] - c0)
            operator = spla.LinearOperator((starts[-1],) * 2, matvec=matvec)
            y, goal, residual = c0, self.tol * float(np.linalg.norm(c0)), np.inf
            for _ in range(RESTARTS):                  # GMRES's own residual estimate can run ahead of
                y, _ = spla.gmres(operator, c0, x0=y, rtol=0.0, atol=goal, restart=self.max_iter,
                                  maxiter=1, callback=lambda r: history.append(float(r)),
                                  callback_type="pr_norm")
                out, lam, partials = run(y)            # the true one (the sweeps' solves are inexact)
                sweeps[0] += 1
                previous, residual = residual, float(np.linalg.norm(out - y))
                if not np.all(np.isfinite(y)) or residual <= goal or residual > 0.1 * previous:
                    break
            relative = residual / float(np.linalg.norm(c0))
            if not np.all(np.isfinite(y)) or relative > FLOOR:
                raise NumericalError(f"adjoint block Gauss-Seidel did not converge in {len(history)} GMRES "
                                     f"iterations (relative residual {relative:.2e})", {"history": history})
        self.reports.append({"method": "block Gauss-Seidel", "sweeps": sweeps[0], "history": history})
        return lam, partials
