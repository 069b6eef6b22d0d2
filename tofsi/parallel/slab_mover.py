"""The mesh mover by slabs: its element kernels on each rank's elements, its tangent across the ranks.

A mover with a residual form (Yeoh, linear elasticity in one increment, the spring analogy in
one increment: :meth:`movers.base.Mover.element_residual`) moves the fluid mesh by solving

    D(x) = W R(x) + S_c (x - t) = 0 on the free dofs,   x_p = t_p on the fixed ones,

``R`` the assembled element residuals ``R_e(x, f_e)`` (``f_e`` the quad's stiffening factor),
``t`` the structure's motion where the mesh follows it, ``W = 1 - s`` and ``S_c = s c`` the
density blend (:mod:`movers.blend`; ``W = 1``, ``S_c = 0`` without one). :class:`SlabMover`
evaluates ``R_e`` and its tangent ``K_e`` with the serial mover's own kernel on the moving quads
of the rank's slab only (a :class:`~movers.problem.MotionProblem` of those quads on the whole
mesh's points), so no rank holds the element tangents, the kernel's Gauss-point temporaries
or the LU factors of the whole mesh:

* nodal sums (``R``, the blend's node scale ``c``, ``K^T v`` on the fixed dofs) are the sum
  over ranks of the slabs' sums (:meth:`~tofsi.parallel.slab_flow.SlabCoupling.allsum`: the
  same bits on every rank, so every rank takes the same Newton decisions);
* the tangent ``P_f (W K + S_c) P_f + P_p`` is assembled by the slabs into a distributed AIJ
  matrix and factorized across the ranks by MUMPS (:class:`~tofsi.parallel.slab_matrix.SlabMatrix`);
* an element is valid where the kernel is defined (Yeoh's needs ``det F > 0``) and, for the movers
  whose serial move refuses them (Yeoh's), no corner Jacobian of the moved quad is non-positive;
  a trial state is valid when it is on every rank (one ``MPI_Allreduce``). Linear elasticity and
  the one-increment spring solve their linear equations whatever the mesh, as serially; the
  coupled state is checked for folds afterwards.

The Newton with load steps, cutbacks and line search is the serial Yeoh mover's own,
:class:`movers.newton.LoadStepNewton`, on these operators (:class:`SlabOperators`).
The adjoint, at the converged ``x`` (:class:`SlabMotionLinearization`):

    D_x^T lam = rhs:   A_ff^T lam_f = rhs_f,   lam_p = rhs_p - (K^T W lam_f)_p,
    lam^T D_(t, f, s) = (-(lam_p + S_c lam_f),  (W lam)_e . dR_e/df_e,  lam_i . (c_i (x_i - t_i) - R_i)),

as :meth:`movers.base.Mover.transposed_solve` and :meth:`~movers.base.Mover.residual_partials`
(``dR_e/df_e`` by the complex step in the factors, on the slab), then chained to ``u`` and
``rho`` by the serial :class:`~tofsi.physics.mesh_motion.MeshMotion` (``target_transpose``,
``density_transpose``: the indicator and the density-grown layers, ``O(E)``, replicated).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from movers.base import MoveReport, element_apply
from movers.blend import Blend
from movers.failure import broken_element
from movers.newton import LoadStepNewton, NewtonSettings
from movers.problem import MotionProblem
from tofsi.core.errors import NumericalError
from tofsi.core.kept import Kept
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.complex_step import derivative
from tofsi.mesh import quality
from tofsi.parallel.slab_matrix import SlabMatrix

CORNER_CHECKED = ("yeoh",)      # movers whose serial move refuses a trial with an inverted corner


@dataclass(frozen=True, eq=False)
class SlabDesign:
    """What the mover's equations read at one design: the slab's quads (stiffening included),
    the blend (None without one) and its per-dof row weights ``W`` and diagonal ``S_c`` (2n,)."""

    slab: MotionProblem
    blend: Blend | None
    weight: np.ndarray
    diag: np.ndarray


@dataclass
class MoverState:
    """The slab's element residuals ``(E_r, 8)`` and tangents (or None), and ``R`` (2n,) summed over ranks."""

    Re: np.ndarray
    Ke: np.ndarray | None
    R: np.ndarray


class SlabMover:
    """The residual-form mover of ``motion`` (a :class:`~tofsi.physics.mesh_motion.MeshMotion`) on
    the slabs of ``coupling``'s engine (a :class:`~tofsi.parallel.slab_flow.SlabCoupling`)."""

    incremental = False      # a move in increments: :class:`tofsi.parallel.slab_increments.SlabIncrementMover`

    def __init__(self, motion, coupling):
        if motion.path_dependent != self.incremental:
            raise ValueError(f"the {motion.mover.name} mover: "
                             + ("no move in increments" if self.incremental else "no residual form to distribute"))
        from mpi4py import MPI
        self.motion, self.mover, self.params = motion, motion.mover, motion.mover.params
        self.allsum, self.mpi, self.land = coupling.allsum, coupling.mpi, MPI.LAND
        base, part, mesh = motion.base, coupling.engine.part, motion.mesh
        in_slab, in_halo = np.zeros(mesh.n_elements, bool), np.zeros(mesh.n_elements, bool)
        in_slab[part.elements], in_halo[part.halo_elements] = True, True
        self.local = np.flatnonzero(in_slab[base.element_ids])                  # the slab's moving quads
        self.quads = base.quads[self.local]
        self.dofs = element_dofs(self.quads, 2)                                  # (E_r, 8), serial numbering
        self.size = 2 * mesh.n_nodes
        self.fixed = np.unique(base.fixed_dofs)
        self.is_fixed = np.zeros(self.size, dtype=bool)
        self.is_fixed[self.fixed] = True
        self.halo = element_dofs(base.quads[in_halo[base.element_ids]], 2)
        self.comm = coupling.engine.comm
        self.matrix = None if self.incremental else self.new_matrix()
        self.corners = self.mover.name in CORNER_CHECKED
        self.kept = Kept()                       # the design's SlabDesign, keyed by the densities
        self.factored_at = None                  # the state whose tangent the factors hold

    def new_matrix(self) -> SlabMatrix:
        """A distributed matrix on the mesh's node dofs, its factors recycled by later matrices."""
        return SlabMatrix(self.comm, self.motion.mesh, self.halo, self.fixed, recycle=True)

    # ---- the design -------------------------------------------------------------------------
    def design(self, rho) -> SlabDesign:
        """The equations' data at densities ``rho`` (kept for the last densities)."""
        return self.kept.get(self.motion.density_key(rho), lambda: self._design(rho))

    def _design(self, rho) -> SlabDesign:
        problem = self.motion.problem(rho)                   # replicated: O(n) blend, O(E) factors
        slab = MotionProblem(points=problem.points, quads=self.quads, fixed_nodes=problem.fixed_nodes,
                             stiffening=problem.stiffening[self.local],
                             element_ids=problem.element_ids[self.local])
        if problem.blend is None:
            return SlabDesign(slab, None, np.ones(self.size), np.zeros(self.size))
        K0 = self.mover.reference_matrices(slab)
        diagonal = self.allsum(assemble_vector(self.dofs, np.diagonal(K0, axis1=1, axis2=2), self.size))
        del K0
        c = diagonal.reshape(-1, 2).mean(axis=1)             # movers.blend.node_scale, summed over ranks
        c = np.where(c > 0, c, c[c > 0].mean() if np.any(c > 0) else 1.0)
        blend = Blend.build(np.asarray(problem.blend, float), c, self.is_fixed)
        return SlabDesign(slab, blend, blend.weight, blend.diag)

    # ---- residual, tangent, solves --------------------------------------------------------------
    def valid_everywhere(self, ok: bool) -> bool:
        return bool(self.mpi.allreduce(bool(ok), op=self.land))

    def evaluate(self, d: SlabDesign, x: np.ndarray, tangent: bool = True) -> MoverState | None:
        """The slab's residuals (and tangents) at ``x`` (2n,), None when an element is invalid on
        any rank (the kernel undefined, e.g. Yeoh's ``det F <= 0``, or a corner Jacobian <= 0)."""
        try:
            Re, Ke = self.mover.element_residual(d.slab, x, d.slab.stiffening, tangent)
            ok = not (self.corners and np.any(quality.inverted(d.slab.points + x.reshape(-1, 2), self.quads)))
        except NumericalError:
            Re, Ke, ok = None, None, False
        if not self.valid_everywhere(ok):
            return None
        return MoverState(Re, Ke, self.allsum(assemble_vector(self.dofs, Re, self.size)))

    def residual(self, d: SlabDesign, R: np.ndarray, x: np.ndarray, target: np.ndarray) -> np.ndarray:
        """``D(x)`` on the free dofs, zero on the fixed ones, from the assembled ``R``."""
        r = d.weight * R + d.diag * (x - target)
        r[self.fixed] = 0.0
        return r

    def apply(self, d: SlabDesign, Ke: np.ndarray, v: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``K v`` (or ``K^T v``) (2n,) summed over ranks, from the slab's element matrices."""
        return self.allsum(element_apply(Ke, v, self.dofs, transpose))

    def factorize(self, d: SlabDesign, Ke: np.ndarray, at=None) -> None:
        """LU of ``P_f (W K + S_c) P_f + P_p`` across the ranks; ``at``: the state it belongs to."""
        self.matrix.factorize(self.dofs, Ke * d.weight[self.dofs][:, :, None], d.diag)
        self.factored_at = at

    def assemble(self, d: SlabDesign, Ke: np.ndarray) -> None:
        """``P_f (W K + S_c) P_f + P_p`` across the ranks, the earlier factors kept (a Newton step's)."""
        self.matrix.assemble(self.dofs, Ke * d.weight[self.dofs][:, :, None], d.diag)
        self.factored_at = None

    def solve(self, b: np.ndarray, transpose: bool = False, rtol: float | None = None) -> np.ndarray:
        """The assembled matrix's (transposed) solve: exact, or GMRES to ``rtol`` with kept factors."""
        return self.matrix.solve(b, transpose, rtol)

    # ---- the forward move -------------------------------------------------------------------------
    def move(self, u, rho, guess=None):
        """``(x (2n,), linearization, report)``: the mesh moved with the structure's ``u`` at ``rho``."""
        d = self.design(rho)
        target = self.motion.target(u).reshape(-1)
        t0, counts = time.perf_counter(), (self.matrix.factorizations, self.matrix.krylov_iterations)
        report = MoveReport(mover=self.mover.name)
        x = LoadStepNewton(SlabOperators(self, d, target), NewtonSettings.of(self.params), report,
                           f"{self.mover.name} mover by slabs").move(guess)
        report.converged, report.wall_time_s = True, time.perf_counter() - t0
        report.factorizations = self.matrix.factorizations - counts[0]           # this move's own
        report.krylov_iterations = self.matrix.krylov_iterations - counts[1]
        return x, SlabMotionLinearization(self, d, x, target, rho), report.as_dict()


class SlabOperators:
    """The equations of :class:`SlabMover` at one design ``d`` towards the motion ``target`` (2n,),
    as :class:`movers.newton.LoadStepNewton` reads them: a state is the slab's
    :class:`MoverState` (None where an element is invalid on some rank), vectors are replicated.
    A mover without Yeoh's Newton parameters (linear elasticity, the spring in one increment)
    takes their defaults (:meth:`movers.newton.NewtonSettings.of`): its residual is linear and
    its tangent constant, so the predictor and a Newton step or two solve it."""

    def __init__(self, mover: SlabMover, d: SlabDesign, target: np.ndarray):
        self.m, self.d, self.target, self.fixed = mover, d, target, mover.fixed

    def evaluate(self, x: np.ndarray, tangent: bool = True) -> MoverState | None:
        return self.m.evaluate(self.d, x, tangent)

    def forces(self, state: MoverState) -> np.ndarray:
        return state.R

    def residual(self, state: MoverState, x: np.ndarray, load: float) -> np.ndarray:
        return self.m.residual(self.d, state.R, x, load * self.target)

    def jump(self, state: MoverState, boundary_step: np.ndarray) -> np.ndarray:
        """Free-row response ``W K_fp d_p`` to moving the fixed dofs by ``d_p``."""
        v = np.zeros_like(boundary_step)
        v[self.fixed] = boundary_step[self.fixed]
        r = self.d.weight * self.m.apply(self.d, state.Ke, v)
        r[self.fixed] = 0.0
        return r

    def solve(self, state: MoverState, rhs: np.ndarray, rtol: float) -> np.ndarray:
        """The tangent's solve to ``rtol``: GMRES preconditioned by an earlier step's factors,
        refactorized when they went stale (:meth:`~tofsi.parallel.slab_matrix.SlabMatrix.solve`)."""
        self.m.assemble(self.d, state.Ke)
        return self.m.solve(rhs, rtol=rtol)

    def nearer(self, x0: np.ndarray) -> bool:
        carried = self.m.is_fixed | (self.d.diag > 0)
        return bool(np.linalg.norm((self.target - x0)[carried]) < np.linalg.norm(self.target[carried]))

    def broken(self, x: np.ndarray) -> dict | None:
        """The most skewed element ``x`` inverts by its corners over all ranks' slabs (the same on
        every rank), None when none is."""
        found = [b for b in self.m.mpi.allgather(broken_element(self.d.slab, x)) if b is not None]
        return min(found, key=lambda b: (b["skewness"], b["element"])) if found else None

    def record(self, report: MoveReport, x: np.ndarray, load: float, planned: int) -> None:
        report.increments += 1

    def fail(self, report: MoveReport, x, message: str, load: float, broken) -> None:
        report.message = message
        raise NumericalError(f"{report.mover} mover (by slabs): {message}",
                             {"report": report.as_dict(), "load": load,
                              **({"broken_element": broken} if broken else {})})


class SlabMotionLinearization:
    """The mover's derivatives at its converged ``x``: transposed solves and partials, by slabs."""

    def __init__(self, mover: SlabMover, design: SlabDesign, x, target, rho):
        self.mover, self.design, self.x, self.target, self.rho = mover, design, x, target, rho
        self.size = x.size
        self.Ke = None

    def solve_transpose(self, rhs: np.ndarray) -> np.ndarray:
        """``D_x^-T rhs`` (2n,): ``lam_f`` on the free dofs, ``lam_p`` on the fixed ones. The tangent
        at ``x`` is factorized on the first call and its factors kept for the adjoint's sweeps."""
        m, d = self.mover, self.design
        if self.Ke is None or m.factored_at is not self:
            e = m.evaluate(d, self.x)
            if e is None:
                raise NumericalError("mover adjoint: the converged mesh is invalid", {})
            self.Ke = e.Ke
            m.factorize(d, self.Ke, at=self)
        rhs = np.asarray(rhs, dtype=float).reshape(-1)
        b = rhs.copy()
        b[m.fixed] = 0.0
        lam = m.solve(b, transpose=True)
        lam[m.fixed] = 0.0
        lam_p = np.zeros_like(rhs)
        lam_p[m.fixed] = rhs[m.fixed] - m.apply(d, self.Ke, d.weight * lam, transpose=True)[m.fixed]
        return lam + lam_p

    def transpose_partials(self, lam: np.ndarray):
        """``({"u": lam^T D_u}, lam^T D_rho)``: (2n,) and (E,), no solve."""
        m, d = self.mover, self.design
        lam = np.asarray(lam, dtype=float).reshape(-1)
        lam_f = lam.copy()
        lam_f[m.fixed] = 0.0
        t_bar = np.zeros_like(lam)
        t_bar[m.fixed] = -lam[m.fixed]
        Re = derivative(lambda f: m.mover.element_residual(d.slab, self.x, f, tangent=False)[0],
                        d.slab.stiffening)                                   # dR_e/df_e (E_r, 8)
        f_bar = np.zeros(len(m.motion.base.quads))
        f_bar[m.local] = np.einsum("ea,ea->e", (d.weight * lam_f)[m.dofs], Re)
        f_bar = m.allsum(f_bar)
        s_bar = np.zeros(self.size // 2)
        if d.blend is not None:
            R = m.allsum(assemble_vector(m.dofs, m.mover.element_residual(d.slab, self.x, d.slab.stiffening,
                                                                           tangent=False)[0], self.size))
            t_blend, s_bar = d.blend.partials(lam_f, self.x, self.target, R)
            t_bar += t_blend
        return ({"u": m.motion.target_transpose(t_bar)},
                m.motion.density_transpose(self.rho, s_bar, f_bar))
