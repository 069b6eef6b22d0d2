"""The adjoint of the distributed flow: a flow objective and its gradient in the densities, by slabs.

At a converged state ``w`` of :class:`~tofsi.parallel.flow_system.DistributedFlow`
(constrained Jacobian ``J_c``: identity on the fixed rows and columns), for an
objective ``f(w, rho) = sum_e f_e(w_e, rho_e)`` each rank

* evaluates ``f_e`` and the element partials ``df_e/dw_e`` ``(E_r, 22)``,
  ``df_e/drho_e`` ``(E_r,)`` on *its own elements* with the registry objective's
  own kernels (read through :class:`SlabView`), and adds the element partials
  into a distributed vector ``g``;
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

from dataclasses import dataclass

import numpy as np

from tofsi.core.errors import InputError

SLAB_OBJECTIVES = ("dissipation", "dissipation-strain")      # element sums of the velocity only


class SlabView:
    """The flow of a :class:`DistributedFlow` restricted to its rank's elements, as an objective's
    kernels read a flow: ``split`` (of the ghosted state, ``(m,)``), ``corners``, ``alpha``,
    ``brinkman``, ``element``, ``settings``, ``dofs`` (into the ghosted state) and ``size``."""

    def __init__(self, engine):
        self.engine = engine
        self.element, self.settings = engine.flow.element, engine.flow.settings
        self.dofs = engine.local                      # (E_r, 22) into engine.ghosts
        self.size = engine.ghosts.size

    def split(self, w_ghost: np.ndarray):
        we = np.asarray(w_ghost)[self.dofs]                                  # (E_r, 22)
        return we[:, :18].reshape(len(we), -1, 2), we[:, 18:]

    def corners(self, x=None) -> np.ndarray:
        return self.engine.corners(x)

    def brinkman(self, params=None):
        return self.engine.flow.brinkman(params)

    def alpha(self, rho_slab: np.ndarray, params=None) -> np.ndarray:
        """Friction of the slab's elements from their densities ``(E_r,)``."""
        return self.brinkman(params)(rho_slab)


@dataclass(frozen=True)
class SlabModel:
    """What an objective reads of the model: the slab's flow (the mesh for shape partials)."""

    flow: SlabView
    mesh: object


@dataclass(frozen=True)
class SlabState:
    """What a flow objective reads of a state, on one slab: the ghosted ``w``, the slab's ``rho``."""

    w: np.ndarray
    rho: np.ndarray
    params: object
    x: None = None
    mesh_displacement: None = None


class SlabObjective:
    """A registry flow objective (``design.objective``) and its adjoint gradient by slabs."""

    def __init__(self, engine, objective):
        if objective.name not in SLAB_OBJECTIVES:
            raise InputError("design.objective", objective.name,
                             f"one of {list(SLAB_OBJECTIVES)} for the distributed flow")
        self.engine, self.objective = engine, objective
        self.view = SlabView(engine)
        self.model = SlabModel(self.view, engine.flow.mesh)
        self.mpi = engine.comm.tompi4py()

    def state(self, rho: np.ndarray, params) -> SlabState:
        e = self.engine
        return SlabState(e.ghost_values(e.w).copy(), np.asarray(rho, dtype=float)[e.part.elements], params)

    def gradient(self, rho: np.ndarray, params) -> tuple[float, np.ndarray]:
        """``(f, df/drho (E,))`` at the engine's converged state, the same on every rank."""
        from mpi4py import MPI
        e, view = self.engine, self.view
        state = self.state(rho, params)
        partials = self.objective.partials(self.model, state)      # "w": (m,) ghosted, "rho": (E_r,)
        g = e.vector_of_ghosts(-partials["w"])                      # -df/dw, distributed
        lam = e.solve_transpose(g)
        lam_e = e.ghost_values(lam)[e.local]                                         # (E_r, 22)
        ve, pe = view.split(state.w)
        Xe = e.corners(None)
        flow = e.flow
        dR_dalpha = flow.element.alpha_partial(Xe, ve, pe, view.alpha(state.rho, params), flow.density,
                                               flow.settings.viscosity, flow.symmetric, None)   # (E_r, 22)
        local = np.zeros(flow.mesh.n_elements)
        local[e.part.elements] = (partials.get("rho", 0.0)
                                  + view.brinkman(params).derivative(state.rho)
                                  * np.einsum("ea,ea->e", dR_dalpha, lam_e))
        total = np.empty_like(local)
        self.mpi.Allreduce(local, total, op=MPI.SUM)
        value = float(self.mpi.allreduce(self.objective.value(self.model, state)))
        g.destroy()
        lam.destroy()
        return value, total
