"""The flow solved across MPI ranks with PETSc: each rank assembles its own slab, Krylov with fieldsplit.

Under ``mpiexec -n P`` every rank builds the (replicated, O(n) integer)
mesh and the :class:`~tofsi.parallel.partition.SlabPartition`, then:

* evaluates the fluid element kernel on **its own elements only**
  (:func:`tofsi.physics.fluid_kernel.fluid_element`, ``(E_r, 22, 22)``),
  reading their dof values from the distributed state through one PETSc
  scatter (its slab's dofs and the ghost layer on each cut);
* adds them into a distributed AIJ matrix and vector
  (``setValuesRCV``: all element blocks in one call, entries owned by the
  neighbour stashed and sent at assembly); the Dirichlet rows and columns are
  eliminated by ``zeroRowsColumns`` (identity on the diagonal), as
  :class:`tofsi.fem.dirichlet.DirichletOperator` does serially;
* solves the Newton steps with PETSc's FGMRES and a Schur-complement
  fieldsplit (upper factorization): GAMG (or hypre's BoomerAMG) on the
  velocity block, and on the pressure the Cahouet-Chabard approximation of
  :mod:`tofsi.linalg.iterative`, ``-S~^{-1} = M_mu^{-1} + L_alpha^{-1}``,
  applied by a Python PC (a diagonal scaling plus one GAMG cycle on
  ``L_alpha = B (alpha M_v)^{-1} B^T``, formed with distributed matrix products).

No rank holds a global matrix or vector; rank 0 gathers the state only
when asked (:meth:`DistributedFlow.gather`). Flows with a body force or a
closed boundary (pinned pressure) are not distributed (InputError).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from tofsi.core.errors import InputError, NumericalError
from tofsi.core.iteration import backtracking, forcing_term
from tofsi.linalg.iterative import FLOOR
from tofsi.parallel.partition import SlabPartition, row_counts
from tofsi.parallel.petsc_support import DarcySchurPC, collect_garbage, petsc
from tofsi.physics.flow_preconditioner import element_areas
from tofsi.physics.flow_view import FlowView
from tofsi.physics.fluid_kernel import fluid_element

if TYPE_CHECKING:                              # annotations only: petsc4py is imported lazily
    from petsc4py import PETSc

log = logging.getLogger(__name__)
CHUNK = 2048                # elements per kernel call (bounds the kernel's temporaries)


class DistributedFlow:
    """The flow of ``flow`` (a :class:`tofsi.physics.flow.Flow`) assembled and solved by slabs.

    amg : ``gamg`` (PETSc's smoothed aggregation) or ``hypre`` (BoomerAMG) for the velocity block
    """

    def __init__(self, flow, comm=None, amg: str = "gamg", rtol: float = 1e-10):
        if not flow.element.block_preconditioned:
            raise InputError("fluid.element", flow.element.name, "q2q1 for the distributed flow (its kernel "
                             "and its Schur complement approximation are Taylor-Hood's)")
        if not flow.open_outlet:
            raise InputError("fluid.<side>.open", "no open segment",
                             "an open outlet for the distributed flow (with every opening's velocity "
                             "prescribed one pressure is pinned, which it does not handle); list an "
                             "open segment in a [fluid.<side>] table, or solve serially")
        if flow.body_force is not None:
            raise ValueError("the distributed flow has no body force term")
        PETSc = petsc()
        self.flow, self.amg, self.rtol = flow, amg, rtol
        self.comm = PETSc.COMM_WORLD if comm is None else comm
        self.part = SlabPartition.of(flow, self.comm.getRank(), self.comm.getSize())
        p = self.part
        lo, hi = p.owned
        n = flow.size
        self.dofs = p.new_of_old[flow.dofs[p.elements]].astype(PETSc.IntType)          # (E_r, 22) new numbering
        self.ghosts = np.unique(self.dofs)                                               # (m,) needed dofs
        self.local = np.searchsorted(self.ghosts, self.dofs)                            # (E_r, 22) into ghosts
        fixed_new = p.new_of_old[flow.bc.fixed]
        self.fixed_owned = np.sort(fixed_new[(fixed_new >= lo) & (fixed_new < hi)]).astype(PETSc.IntType)
        self.values_new = np.zeros(n)
        self.values_new[p.new_of_old] = flow.values                                      # boundary values
        self.mat = PETSc.Mat().createAIJ(((hi - lo, n), (hi - lo, n)), comm=self.comm)
        self.mat.setPreallocationNNZ(self._row_counts())
        self.mat.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        self.w = self.mat.createVecRight()
        self.r = self.mat.createVecLeft()
        self.ghost_vec = PETSc.Vec().createSeq(self.ghosts.size, comm=PETSc.COMM_SELF)
        self.scatter = PETSc.Scatter().create(self.w, PETSc.IS().createGeneral(self.ghosts, comm=PETSc.COMM_SELF),
                                              self.ghost_vec, None)
        self.is_v = PETSc.IS().createGeneral(p.velocity.astype(PETSc.IntType), comm=self.comm)
        self.is_p = PETSc.IS().createGeneral(p.pressure.astype(PETSc.IntType), comm=self.comm)
        self.krylov_iterations = 0
        self.linearized_at = None         # (x, rho, params) of the converged self.mat
        self.transposed = None            # (linearized_at, J_c^T, its KSP) while an adjoint runs
        self.transposed_iterations = 0

    def _row_counts(self):
        """Exact preallocation from the elements touching owned dofs (:func:`row_counts`)."""
        lo, hi = self.part.owned
        return row_counts(self.part.new_of_old[self.flow.dofs[self.part.halo_elements]], lo, hi, self.flow.size)

    # ---- state --------------------------------------------------------------------
    def set_state(self, w_old: np.ndarray) -> None:
        """The distributed state from a whole vector in the flow's numbering (every rank has it)."""
        lo, hi = self.part.owned
        inverse = np.empty_like(self.part.new_of_old)
        inverse[self.part.new_of_old] = np.arange(inverse.size)
        self.w.setArray(np.asarray(w_old)[inverse[lo:hi]])

    def initial(self) -> None:
        lo, hi = self.part.owned
        self.w.setArray(self.values_new[lo:hi])

    def gather(self):
        """The whole state in the flow's numbering on rank 0 (None elsewhere)."""
        PETSc = petsc()
        scatter, whole = PETSc.Scatter.toZero(self.w)
        scatter.scatter(self.w, whole, PETSc.InsertMode.INSERT_VALUES, PETSc.ScatterMode.FORWARD)
        out = None
        if self.comm.getRank() == 0:
            out = whole.getArray()[self.part.new_of_old].copy()
        scatter.destroy()
        whole.destroy()
        return out

    def ghost_values(self, w: "PETSc.Vec") -> np.ndarray:
        """``(m,)``: the entries of the distributed ``w`` at :attr:`ghosts` (every dof the slab's
        elements touch), through one scatter; ``self.local`` indexes them by element."""
        PETSc = petsc()
        self.scatter.scatter(w, self.ghost_vec, PETSc.InsertMode.INSERT_VALUES, PETSc.ScatterMode.FORWARD)
        return self.ghost_vec.getArray()

    def slab_values(self, w: "PETSc.Vec"):
        """The slab's element velocities ``(E_r, 9, 2)`` and pressures ``(E_r, 4)`` of ``w``."""
        we = self.ghost_values(w)[self.local]                                           # (E_r, 22)
        return we[:, :18].reshape(-1, 9, 2), we[:, 18:]

    def vector_of_ghosts(self, values: np.ndarray) -> "PETSc.Vec":
        """A new distributed vector, the sum over ranks of their ghosted values ``(m,)`` (a dof on
        a cut gets both slabs' contributions)."""
        PETSc = petsc()
        v = self.mat.createVecLeft()
        v.zeroEntries()
        v.setValues(self.ghosts, np.asarray(values, dtype=float), addv=PETSc.InsertMode.ADD_VALUES)
        v.assemble()
        return v

    def view(self, rho, params=None) -> FlowView:
        """The converged state's flow on this rank's elements, as objectives read it (the
        flow's own :class:`~tofsi.physics.flow_view.FlowView`: its dofs index the ghosted state)."""
        flow, elements = self.flow, self.part.elements
        rho_slab = np.asarray(rho, dtype=float)[elements]
        c = flow.coefficients(rho, params)
        Xe = self.corners(None)
        return FlowView(flow.element, Xe, self.ghost_values(self.w)[self.local], self.local, self.ghosts.size,
                        rho_slab, replace(c, alpha=c.alpha[elements]),
                        flow.element.basis(Xe) if flow.element.keeps_basis else None)

    # ---- assembly -----------------------------------------------------------------
    def corners(self, x=None) -> np.ndarray:
        """The slab's corner coordinates ``(E_r, 4, 2)`` on the mesh moved by ``x`` (n, 2)."""
        mesh = self.flow.mesh
        quads = mesh.quads[self.part.elements]
        return (mesh.points[quads] if x is None else (mesh.points + x)[quads])       # (E_r, 4, 2)

    def assemble(self, w, x, rho, density, jacobian: bool = True, params=None) -> float:
        """Residual (``self.r``, fixed rows zeroed) and, if asked, the constrained Jacobian
        (``self.mat``) of the slab's elements at ``w``; returns ``|R|``. The kernel runs on
        chunks of :data:`CHUNK` elements, each added at once, so its temporaries stay small."""
        PETSc = petsc()
        flow = self.flow
        ADD = PETSc.InsertMode.ADD_VALUES
        ve, pe = self.slab_values(w)
        alpha = flow.alpha(rho, params)[self.part.elements]
        corners = self.corners(x)
        self.r.zeroEntries()
        if jacobian:
            self.mat.zeroEntries()
        for a in range(0, len(self.dofs), CHUNK):
            b = a + CHUNK
            Re, Ke = fluid_element(corners[a:b], ve[a:b], pe[a:b], alpha[a:b], density,
                                   flow.settings.viscosity, flow.symmetric, jacobian)   # (c, 22), (c, 22, 22)
            self.r.setValues(self.dofs[a:b].ravel(), Re.ravel(), addv=ADD)
            if jacobian:
                self.mat.setValuesRCV(self.dofs[a:b], self.dofs[a:b], Ke, addv=ADD)
            del Re, Ke
        self.r.assemble()
        lo, _ = self.part.owned
        self.r.getArray()[self.fixed_owned - lo] = 0.0
        if jacobian:
            self.mat.assemble()
            self.mat.zeroRowsColumns(self.fixed_owned, diag=1.0)
        return self.r.norm()

    def _schur_parts(self, x, rho, params):
        """``M_mu`` (pressure) and ``1/(alpha M_v)`` (velocity, 0 on fixed) as distributed vectors."""
        PETSc = petsc()
        flow, p = self.flow, self.part
        mu = flow.settings.viscosity
        area = element_areas(self.corners(x))                                          # (E_r,)
        alpha = np.maximum(flow.alpha(rho, params)[p.elements], FLOOR * mu / area)
        lumped = np.concatenate([np.repeat(alpha * area / 9, 18).reshape(-1, 18),
                                 np.repeat(area / (4 * mu), 4).reshape(-1, 4)], axis=1)  # (E_r, 22)
        v = self.mat.createVecLeft()
        v.setValues(self.dofs.ravel(), lumped.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
        v.assemble()
        mass, friction = (self._sub_copy(v, self.is_p), self._sub_copy(v, self.is_v))
        v.destroy()
        friction.reciprocal()
        fixed_v = self.fixed_owned[np.isin(self.fixed_owned, p.velocity)]
        friction.getArray()[np.searchsorted(p.velocity, fixed_v)] = 0.0
        return mass, friction

    @staticmethod
    def _sub_copy(v, index_set):
        """A copy of ``v``'s entries on ``index_set`` (the view restored, so nothing leaks)."""
        view = v.getSubVector(index_set)
        out = view.copy()
        v.restoreSubVector(index_set, view)
        return out

    def _ksp(self, mat, x, rho, params):
        """FGMRES with the fieldsplit Schur preconditioner of the assembled ``mat`` (``self.mat``
        or its transpose: ``B`` and ``B^T`` are read from ``mat``'s off-diagonal blocks)."""
        PETSc = petsc()
        mass, weights = self._schur_parts(x, rho, params)
        B = mat.createSubMatrix(self.is_p, self.is_v)
        Bt = mat.createSubMatrix(self.is_v, self.is_p)
        Bt.diagonalScale(L=weights)
        L = B.matMult(Bt)                                                                # (n_p, n_p) distributed
        for used in (B, Bt, weights):                     # L holds what the PC needs
            used.destroy()
        ksp = PETSc.KSP().create(comm=self.comm)
        ksp.setOperators(mat)
        ksp.setType("fgmres")
        ksp.setGMRESRestart(50)
        pc = ksp.getPC()
        pc.setType("fieldsplit")
        pc.setFieldSplitIS(("v", self.is_v), ("p", self.is_p))
        pc.setFieldSplitType(PETSc.PC.CompositeType.SCHUR)
        pc.setFieldSplitSchurFactType(PETSc.PC.SchurFactType.UPPER)
        pc.setFieldSplitSchurPreType(PETSc.PC.SchurPreType.USER, L)
        pc.setUp()
        kv, kp = pc.getFieldSplitSubKSP()
        kv.setType("preonly")
        kv.getPC().setType(self.amg)
        if self.amg == "hypre":
            kv.getPC().setHYPREType("boomeramg")
        kp.setType("preonly")
        ppc = kp.getPC()
        ppc.setType("python")
        ppc.setPythonContext(DarcySchurPC(mass, L, self.amg))
        ksp.setFromOptions()
        return ksp

    def _transposed_ksp(self):
        """The fieldsplit FGMRES of ``J_c^T`` at the last converged solve, kept (a coupled
        adjoint's sweeps solve several times there) until :meth:`release_transpose`."""
        if self.transposed is None or self.transposed[0] is not self.linearized_at:
            self.release_transpose()
            mat_t = self.mat.transpose(petsc().Mat())          # (petsc4py: no argument = in place)
            self.transposed = (self.linearized_at, mat_t, self._ksp(mat_t, *self.linearized_at))
        return self.transposed[2]

    def release_transpose(self) -> None:
        """Free the transposed matrix and its hierarchies (after an adjoint, before a solve)."""
        if self.transposed is not None:
            self.transposed[2].destroy()
            self.transposed[1].destroy()
            self.transposed = None
            collect_garbage(self.comm)

    def solve_transpose(self, b: "PETSc.Vec", rtol: float = 1e-11) -> "PETSc.Vec":
        """``lam`` with ``J_c^T lam = b`` on the converged constrained Jacobian of the last
        :meth:`solve` (``b``'s fixed entries zeroed, so ``lam``'s are zero: the serial
        adjoint's homogenized multipliers), to ``|b - J_c^T lam| <= rtol |b|``: FGMRES with
        the Schur fieldsplit of the explicitly transposed matrix ``J_c^T`` (one more matrix
        while the adjoint runs, kept with its hierarchies: :meth:`_transposed_ksp`). PETSc
        3.18's ``KSPSolveTranspose`` with the fieldsplit stagnates at 1e-4 after 1000
        iterations on a Navier-Stokes Jacobian, hence the explicit transpose."""
        if self.linearized_at is None:
            raise NumericalError("distributed flow adjoint: no converged solve to transpose", {})
        lo, _ = self.part.owned
        b.getArray()[self.fixed_owned - lo] = 0.0
        ksp = self._transposed_ksp()
        ksp.setTolerances(rtol=rtol, atol=0.0, max_it=1000)
        lam = self.mat.createVecRight()
        ksp.solve(b, lam)
        its, reason = ksp.getIterationNumber(), ksp.getConvergedReason()
        check = b.duplicate()
        self.mat.multTranspose(lam, check)
        check.aypx(-1.0, b)
        relative = check.norm() / max(b.norm(), 1e-300)
        log.info("FGMRES transposed (fieldsplit): %d iterations, reason %d, |b - J^T lam|/|b| = %.2e",
                 its, reason, relative)
        self.transposed_iterations = its
        check.destroy()
        if reason < 0 or relative > 10 * rtol:
            raise NumericalError("distributed flow adjoint: transposed Krylov solve failed",
                                 {"reason": reason, "iterations": its, "relative_residual": relative})
        return lam

    # ---- Newton ---------------------------------------------------------------------
    def solve(self, x=None, rho=None, params=None, w0=None, warm: bool = False) -> dict:
        """Steady flow (Newton, inexact Krylov steps, backtracking on ``|R|``); the state stays
        distributed in ``self.w``, the converged Jacobian in ``self.mat`` (for
        :meth:`solve_transpose`). Starts from ``w0`` (a whole vector), or with ``warm`` from
        the current ``self.w`` (its fixed values reset), else from the boundary values.
        Returns the report (same on every rank)."""
        flow, s = self.flow, self.flow.settings
        t0 = time.perf_counter()
        start = self.w.copy() if warm else None
        self.release_transpose()
        self.linearized_at = None
        self.initial()                  # the force scale: |F| of the all-fluid boundary-value state
        scale = max(self.assemble(self.w, x, None, flow.density, jacobian=False, params=params),
                    1e-14 * max(1.0, abs(s.inlet_velocity)))
        if w0 is not None:
            self.set_state(w0)
        elif start is not None:
            lo, _ = self.part.owned
            start.getArray()[self.fixed_owned - lo] = self.values_new[self.fixed_owned]
            start.copy(self.w)
            start.destroy()
        target = s.newton_tol * scale
        history: list[float] = []
        norm = self.assemble(self.w, x, rho, flow.density, params=params)
        ksp = self._ksp(self.mat, x, rho, params)
        dw = self.w.duplicate()
        try:
            for it in range(s.newton_max_iter + 1):
                history.append(norm)
                log.info("distributed flow Newton %d: |R| = %.3e, target %.3e", it, norm, target)
                if not np.isfinite(norm):
                    raise NumericalError("distributed flow solve: non-finite residual", {"history": history})
                if norm <= target:
                    self.linearized_at = (x, rho, params)
                    return {"converged": True, "newton_iterations": it, "residual_history": history,
                            "krylov_iterations": self.krylov_iterations, "wall_time_s": time.perf_counter() - t0}
                if it == s.newton_max_iter:
                    break
                ksp.setTolerances(rtol=max(forcing_term(history, target), self.rtol), max_it=500)
                if it > 0:
                    ksp.setOperators(self.mat)
                self.r.scale(-1.0)
                ksp.solve(self.r, dw)
                self.krylov_iterations += ksp.getIterationNumber()
                log.info("FGMRES (fieldsplit): %d iterations, reason %d", ksp.getIterationNumber(),
                         ksp.getConvergedReason())
                if ksp.getConvergedReason() < 0:
                    raise NumericalError("distributed flow: Krylov solve failed",
                                         {"reason": ksp.getConvergedReason(), "history": history})
                dw.getArray()[self.fixed_owned - self.part.owned[0]] = 0.0     # the boundary values stay
                base = self.w.copy()

                def trial(alpha, dw=dw, base=base):
                    self.w.waxpy(alpha, dw, base)
                    merit = self.assemble(self.w, x, rho, flow.density, jacobian=(alpha == 1.0), params=params)
                    return merit, merit
                found = backtracking(norm, trial)
                if found is None:
                    raise NumericalError("distributed flow: line search found no decrease", {"history": history})
                alpha, norm = found
                if alpha != 1.0:
                    self.w.waxpy(alpha, dw, base)
                    norm = self.assemble(self.w, x, rho, flow.density, params=params)
                base.destroy()
            raise NumericalError(f"distributed flow: no convergence in {s.newton_max_iter} Newton iterations",
                                 {"history": history})
        finally:                        # the hierarchies go now, not at the next garbage collection
            ksp.destroy()
            dw.destroy()
            collect_garbage(self.comm)
