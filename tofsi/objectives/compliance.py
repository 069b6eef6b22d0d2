"""``compliance``: ``f(w, x, rho) . u`` [J/m], the work of the fluid load on the structure."""

from __future__ import annotations

import numpy as np

from tofsi.objectives import Objective
from tofsi.core.registry import OBJECTIVES


@OBJECTIVES.register
class Compliance(Objective):
    """The work of the fluid load on the structure's displacement, ``f(w, x, rho) . u`` [J/m]."""

    name, needs, label, units = "compliance", "structure", "compliance", "J/m"

    def value(self, model, state) -> float:
        return float(model.structure.load(state.w, state.mesh_displacement, state.rho, state.params) @ state.u)

    def partials(self, model, state) -> dict:
        st, X, rho, params, u = model.structure, state.mesh_displacement, state.rho, state.params, state.u
        force = st.force
        out = {"u": st.load(state.w, X, rho, params),
               "w": force.fluid_partial_transpose(u, state.w, X, rho, params),
               "rho": np.einsum("ea,ea->e", u[st.dofs], force.density_vectors(state.w, X, rho, params))}
        if state.x is not None:                       # the flow saw the moved mesh
            out["x"] = force.shape_partial_transpose(u, state.w, X, rho, params)
        return out
