"""The partial-derivative blocks of S, D and F at a coupled state, assembled once.

Blocks come from the physics modules' own kernels (the same code as the
residuals, so they cannot drift apart) and exist only for the fields the
scene enables: a one-way scene has no ``S_x``, ``F_x`` or ``D``; a scene
without a structure has only ``F``. Each block is built on first use and
kept for every further quantity at the same state.
"""

from __future__ import annotations

import numpy as np


class Blocks:
    """Lazily assembled ``S_w, S_x, S_rho, F_w, F_x, F_rho`` of ``model`` at ``state``."""

    def __init__(self, model, state):
        self.model, self.state = model, state
        self._cache: dict = {}

    def _get(self, name, build):
        if name not in self._cache:
            self._cache[name] = build()
        return self._cache[name]

    @property
    def X(self):
        return self.state.displacement

    # structure
    def S_w(self):
        st = self.model.structure
        return self._get("S_w", lambda: st.bc.free_rows(st.fluid_partial(self.X, self.state.rho)))

    def S_x(self):
        st, s = self.model.structure, self.state
        return self._get("S_x", lambda: st.bc.free_rows(st.shape_partial(s.w, self.X, s.rho)))

    def S_rho(self):
        st, s = self.model.structure, self.state
        return self._get("S_rho", lambda: st.bc.free_rows(st.density_partial(s.u, s.w, self.X, s.rho)))

    # flow
    def F_w(self):
        fl, s = self.model.flow, self.state

        def build():
            last = getattr(fl, "_last", None)
            if last is not None and last[0] is s.w:
                return last[1]
            return fl.jacobian(s.w, self.X, s.rho)[0]
        return self._get("F_w", build)

    def F_x(self):
        fl, s = self.model.flow, self.state
        return self._get("F_x", lambda: fl.bc.free_rows(fl.shape_partial(s.w, self.X, s.rho)))

    def F_rho(self):
        fl, s = self.model.flow, self.state
        return self._get("F_rho", lambda: fl.bc.free_rows(fl.density_partial(s.w, self.X, s.rho)))

    def all(self) -> dict:
        """Every block the scene has (for timing and checks)."""
        names = ["F_w", "F_rho"]
        if self.model.structure is not None:
            names += ["S_w", "S_rho"]
        if self.model.two_way:
            names += ["S_x", "F_x"]
        return {n: getattr(self, n)() for n in names}


def zero(size: int) -> np.ndarray:
    return np.zeros(size)
