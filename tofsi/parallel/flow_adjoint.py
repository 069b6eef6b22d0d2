"""The adjoint of the distributed flow: a flow objective and its gradient in the densities, by slabs.

At a converged state ``w`` of :class:`~tofsi.parallel.flow_system.DistributedFlow`
(constrained Jacobian ``J_c``: identity on the fixed rows and columns), for an
objective ``f(w, rho) = sum_e f_e(w_e, rho_e)`` each rank

* evaluates ``f_e`` and the element partials ``df_e/dw_e`` ``(E_r, 22)``,
  ``df_e/drho_e`` ``(E_r,)`` on *its own elements* with the registry objective's
  own methods (a :class:`~tofsi.objectives.FlowObjective`'s ``element_values`` and
  ``element_partials``) on the slab's :class:`~tofsi.physics.flow_view.FlowView`
  (:meth:`~tofsi.parallel.flow_system.DistributedFlow.view`: the flow's own record,
  its dofs into the ghosted state), and adds the element partials into a
  distributed vector ``g``;
* solves ``J_c^T lam = -g`` (fixed rows of ``g`` zeroed: the serial adjoint's
  homogenized multipliers, :class:`tofsi.fields.flow.FlowLinearization`)
  with the Newton's FGMRES and Schur fieldsplit, transposed
  (:meth:`~tofsi.parallel.flow_system.DistributedFlow.solve_transpose`);
* forms ``df/drho_e = df_e/drho_e + (dR_e/drho_e)^T lam_e`` on its elements
  (``dR_e/drho_e = dR_e/dalpha_e alpha'(rho_e)``, the element's
  ``alpha_partial`` kernel, as :meth:`tofsi.physics.flow.Flow.density_vectors`).

The objective is summed and the gradient (an E-vector, each entry written by
the one rank owning its element) combined by ``MPI_Allreduce``: every rank
ends with the same value and the same replicated ``(E,)`` gradient.
"""

from __future__ import annotations

import numpy as np

from tofsi.core.errors import InputError
from tofsi.core.registry import OBJECTIVES
from tofsi.fem.assembly import assemble_vector
from tofsi.objectives import FlowObjective


def slab_objectives() -> list[str]:
    """The registry's objectives the slabs can differentiate: those summed over the flow's
    elements (:class:`~tofsi.objectives.FlowObjective`)."""
    return [o.name for o in OBJECTIVES if issubclass(o, FlowObjective)]


def check_objective(name: str) -> None:
    """Refuse an objective that is no sum over the flow's elements (before anything is built)."""
    if not issubclass(OBJECTIVES.get(name), FlowObjective):
        raise InputError("design.objective", name, f"one of {slab_objectives()} for the distributed flow "
                         "(a sum over the flow's elements: tofsi.objectives.FlowObjective)")


class SlabObjective:
    """A registry flow objective (``design.objective``) and its adjoint gradient by slabs."""

    def __init__(self, engine, objective):
        check_objective(objective.name)
        self.engine, self.objective = engine, objective
        self.mpi = engine.comm.tompi4py()

    def gradient(self, rho: np.ndarray, params) -> tuple[float, np.ndarray]:
        """``(f, df/drho (E,))`` at the engine's converged state, the same on every rank."""
        from mpi4py import MPI
        e = self.engine
        view = e.view(rho, params)                                  # the slab's flow
        dw, drho = self.objective.element_partials(view)            # (E_r, 22), (E_r,)
        g = e.vector_of_ghosts(-assemble_vector(view.dofs, dw, view.size))       # -df/dw, distributed
        lam = e.solve_transpose(g)
        lam_e = e.ghost_values(lam)[view.dofs]                                   # (E_r, 22)
        c = view.coefficients
        dR_dalpha = view.element.alpha_partial(view.Xe, view.ve, view.pe, c.alpha, c.density, c.viscosity,
                                               c.symmetric, None, view.basis)   # (E_r, 22)
        local = np.zeros(e.flow.mesh.n_elements)
        local[e.part.elements] = drho + c.brinkman.derivative(view.rho) * np.einsum("ea,ea->e", dR_dalpha, lam_e)
        total = np.empty_like(local)
        self.mpi.Allreduce(local, total, op=MPI.SUM)
        value = float(self.mpi.allreduce(float(self.objective.element_values(view).sum())))
        g.destroy()
        lam.destroy()
        e.release_transpose()
        return value, total
