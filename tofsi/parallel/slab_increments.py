"""A mover in increments by slabs: each increment's solve on the updated mesh across the ranks, and its sweeps.

The spring analogy and linear elasticity with ``increments = N > 1`` have no residual form: they
apply the structure's motion ``t`` in ``N`` equal steps ``d = t / N`` on the updated mesh
(:mod:`movers.incremental`), increment ``k`` solving

    A_k dx = [W (-K_k d_p) + S_c d]_f,  dx_p = d_p,   A_k = P_f (W K_k + S_c) P_f + P_p,
    K_k = sum_e f_e K0_e(X + y_k),   x_(k+1) = x_k + dx,

``y_k = x_k + a (x_k - x_(k-1))`` the increment's stiffness point (``a = 0``: its start; the
spring's ``scheme = "midpoint"``: ``a = 1/2``, :class:`movers.increment_kernel.IncrementKernel`).

:class:`SlabIncrementMover` does that with the serial mover's own element kernel
(:class:`movers.increment_kernel.IncrementKernel`) on the moving quads of the rank's slab only: each
rank evaluates ``K0_e(X + y_k)`` of its quads, the right-hand side is the sum over ranks of the
slabs' products, and ``A_k`` is assembled by the slabs into a distributed AIJ matrix
(:class:`~tofsi.parallel.slab_matrix.SlabMatrix`, one per increment) solved by GMRES to
``1e-3 linear_tol`` preconditioned by MUMPS factors of increment ``k``'s system in an earlier move
at the design, refactorized across the ranks when they go stale (what
:class:`movers.increment_solvers.IncrementSolvers` does serially). The spring's selective
diagonals come from two trial increments (every quad split 1-3, then 2-4) solved the same way,
each rank choosing for its own quads by their skewness. ``x_k`` (2n,) and the quality per
increment are replicated.

The derivatives of a move (:class:`SlabIncrements`, built on first use) follow
:func:`movers.incremental.increments_jvp` and :func:`~movers.incremental.increments_vjp`
term by term, each rank holding its quads' share: the element forces ``K0_e dx_e``, the rows
``W f K0_e`` of the quads with a fixed dof, the shape derivative ``W f D_k`` of the forces
(:meth:`~movers.increment_kernel.IncrementKernel.force_derivative`) as element blocks ``(E_r, 8, 8)``,
applied and summed over the ranks; the solves with ``A_k`` and ``A_k^T`` by the exact MUMPS
factors of the move's own ``A_k`` (made on first use; they then precondition the next moves, as
the serial store gives its factors back). The stiffening's and the blend's adjoints are chained
to ``rho`` by the serial :class:`~tofsi.physics.mesh_motion.MeshMotion` (``O(E)``, replicated).
"""

from __future__ import annotations

import itertools
import time

import numpy as np

from movers.base import MoveReport, element_apply, quality_record
from movers.failure import at as place, non_finite_matrices
from movers.increment_solvers import KEPT_FACTORS_TOL_RATIO
from movers.increment_kernel import schedule, stiffness_points
from movers.spring_kernel import DIAGONALS
from tofsi.core.errors import NumericalError
from tofsi.fem.assembly import assemble_vector
from tofsi.mesh import quality
from tofsi.parallel.slab_mover import SlabDesign, SlabMover


class SlabIncrementMover(SlabMover):
    """The mover in increments of ``motion`` (a :class:`~tofsi.physics.mesh_motion.MeshMotion`) on
    the slabs of ``coupling``'s engine: :meth:`move` returns ``(x, linearization, report)`` as
    :meth:`SlabMover.move` does, the linearization an explicit map's (:class:`SlabMoveLinearization`)."""

    incremental = True

    def __init__(self, motion, coupling):
        super().__init__(motion, coupling)
        self.n = int(self.params.increments)
        triangulated = getattr(self.params, "diagonals", None) is not None       # the spring's kernel takes codes
        self.fractions = schedule(self.kernel(np.zeros(len(self.quads), dtype=int) if triangulated else None),
                                  self.n)[0]     # each increment's share of the motion (the settings' alone)
        self.matrices = [self.new_matrix() for _ in range(self.n)]     # increment k's system
        self.trials = {}                                 # the spring's selective diagonals: code -> matrix
        self.owners = [None] * self.n                    # the move (its token) whose A_k each matrix holds
        self.tokens = itertools.count()
        self.rtol = KEPT_FACTORS_TOL_RATIO * float(getattr(self.params, "linear_tol", 1e-10))
        self.design_key = None                           # the densities the kept factors belong to

    def kernel(self, codes: np.ndarray | None = None):
        """The serial mover's :class:`~movers.increment_kernel.IncrementKernel` of the slab's quads
        (a mover that triangulates its quads, the spring: for the diagonal ``codes`` of those quads)."""
        return self.mover.element_matrices() if codes is None else self.mover.element_matrices(codes)

    def solver_counts(self) -> tuple[int, int]:
        every = [*self.matrices, *self.trials.values()]
        return sum(m.factorizations for m in every), sum(m.krylov_iterations for m in every)

    # ---- one increment ----------------------------------------------------------------------
    def system(self, d: SlabDesign, kernel, x: np.ndarray, step: np.ndarray, matrix) -> tuple[np.ndarray, np.ndarray]:
        """Assemble an increment's ``A`` with the stiffness at ``x`` (2n,, its stiffness point)
        into ``matrix``; returns its right-hand side
        ``[W (-K d_p) + S_c d]_f, d_p`` and the slab's unscaled element matrices ``K0 (E_r, 8, 8)``."""
        Xe = d.slab.points[self.quads] + x.reshape(-1, 2)[self.quads]
        K0 = kernel(Xe)
        finite = np.isfinite(K0).all(axis=(1, 2))
        if not self.valid_everywhere(finite.all()):      # decided by all ranks: none is left in MUMPS
            raise non_finite_matrices(np.concatenate(self.mpi.allgather(d.slab.element_ids[~finite])))
        Ke = K0 * d.slab.stiffening[:, None, None]
        step_p = np.where(self.is_fixed, step, 0.0)
        rhs = -self.apply(d, Ke, step_p) if np.any(step_p) else np.zeros_like(step)
        rhs = d.weight * rhs + d.diag * step
        rhs[self.fixed] = step[self.fixed]
        matrix.assemble(self.dofs, Ke * d.weight[self.dofs][:, :, None], d.diag)
        return rhs, K0

    def increment(self, d, kernel, at, step, matrix, rtol) -> np.ndarray:
        """The change ``dx`` (2n,) of one increment by ``step``, its stiffness at ``at`` (2n,)."""
        rhs, _ = self.system(d, kernel, at, step, matrix)
        dx = matrix.solve(rhs, rtol=rtol)
        if not np.all(np.isfinite(dx)):                  # replicated: the same decision on every rank
            raise NumericalError("the increment's solve across the ranks is not finite", {})
        dx[self.fixed] = step[self.fixed]                # exact, whatever the solver's tolerance
        return dx

    def diagonals(self, d: SlabDesign, step: np.ndarray) -> np.ndarray:
        """The spring's selective diagonals of the slab's quads: of two trial first increments
        (every quad 1-3, every quad 2-4), the one leaving the quad less skewed (ties: 1-3)."""
        skew = []
        for code in (0, 1):
            matrix = self.trials.setdefault(code, self.new_matrix())
            codes = np.full(len(self.quads), code)
            dx = self.increment(d, self.kernel(codes), np.zeros_like(step), step, matrix,
                                float(getattr(self.params, "linear_tol", 1e-10)))
            skew.append(quality.skewness(d.slab.points + dx.reshape(-1, 2), self.quads))
        return np.where(skew[1] > skew[0], 1, 0)

    def failure(self, report: MoveReport, problem, x: np.ndarray, k: int, err: NumericalError) -> NumericalError:
        """The error of increment ``k`` failing from the accepted ``x`` (2n,, replicated): the same
        message and diagnostic on every rank, with the worst element of ``x`` where the mesh had moved."""
        quality_now = quality_record(problem, x.reshape(-1, 2), float(np.sum(self.fractions[:k])))
        where = "" if not np.any(x) else (
            f"; after increment {k} the worst element is {quality_now['worst_element']} (skewness "
            f"{quality_now['min_skewness']:.3g}, {quality_now['n_inverted']} inverted) at {place(quality_now['worst_location'])}")
        return NumericalError(f"{report.mover} mover (by slabs): {err} at increment {k + 1} of {self.n}{where}",
                              {"report": report.as_dict(), "quality": quality_now, **err.diagnostic},
                              state=x.reshape(-1, 2))

    # ---- the forward move -------------------------------------------------------------------
    def move(self, u, rho, guess=None):
        """``(x (2n,), linearization, report)``: the mesh moved in increments with the structure's
        ``u`` at ``rho`` (``guess`` is not used: a move in increments starts from rest)."""
        d = self.design(rho)
        key = self.motion.density_key(rho)
        if key != self.design_key:                       # a new design starts afresh, as serially
            for matrix in [*self.matrices, *self.trials.values()]:
                matrix.expire()
            self.design_key = key
        problem = self.motion.problem(rho)               # replicated: the quality records
        prescribed = self.motion.target(u).reshape(-1)
        if not np.all(np.isfinite(prescribed)):          # replicated: refused on every rank alike
            raise NumericalError(f"{self.mover.name} mover (by slabs): prescribed displacement contains NaN or inf", {})
        target = prescribed.copy() if d.blend is not None else np.where(self.is_fixed, prescribed, 0.0)
        t0, counts = time.perf_counter(), self.solver_counts()
        report = MoveReport(mover=self.mover.name)
        codes, choice = None, getattr(self.params, "diagonals", None)      # the spring's triangulation
        if choice is not None:
            codes = (self.diagonals(d, self.fractions[0] * target) if choice == "selective"
                     else np.full(len(self.quads), DIAGONALS.index(choice)))
            report.linear_solves += 2 if choice == "selective" else 0
        kernel = self.kernel(codes)
        extrapolations = schedule(kernel, self.n)[1]
        lin = SlabMoveLinearization(self, d, kernel, target, rho, next(self.tokens))
        x = np.zeros_like(target)
        states, dx = [x], None
        for k in range(self.n):
            a = extrapolations[k]
            at = x + a * dx if a and dx is not None else x
            try:
                dx = self.increment(d, kernel, at, self.fractions[k] * target, self.matrices[k], self.rtol)
            except NumericalError as err:
                report.message = str(err)
                raise self.failure(report, problem, x, k, err) from err
            self.owners[k] = lin.token
            x = x + dx
            states.append(x)
            report.linear_solves += 1
            report.increments += 1
            report.quality.append(quality_record(problem, x.reshape(-1, 2), float(np.sum(self.fractions[:k + 1]))))
        lin.states = states
        last = report.quality[-1]
        now = self.solver_counts()
        report.factorizations, report.krylov_iterations = now[0] - counts[0], now[1] - counts[1]
        report.wall_time_s = time.perf_counter() - t0
        if last["n_inverted"] and not problem.accept_inverted:
            report.message = (f"{last['n_inverted']} inverted element(s); worst element {last['worst_element']} "
                              f"(skewness {last['min_skewness']:.2g}) at {place(last['worst_location'])}")
            raise NumericalError(f"{report.mover} mover (by slabs): {report.message}",
                                 {"report": report.as_dict(), "quality": last}, state=x.reshape(-1, 2))
        if last["n_inverted"]:
            report.message = f"{last['n_inverted']} inverted element(s), accepted"
        report.converged = True
        return x, lin, report.as_dict()


class SlabMoveLinearization:
    """A move in increments as the explicit map ``x = M(u, rho)`` (the residual ``x - M``): the
    transposed solve is the identity, the transposed partials minus the reverse sweep
    (:meth:`vjp`); :meth:`jvp` the tangent sweep. What the sweeps share is built on first use
    (:class:`SlabIncrements`)."""

    def __init__(self, mover: SlabIncrementMover, design: SlabDesign, kernel, target, rho, token: int):
        self.mover, self.design, self.kernel, self.target, self.rho = mover, design, kernel, target, rho
        self.token = token                               # which move's systems the mover's matrices hold
        self.states: list[np.ndarray] = []
        self.increments = None

    def derivatives(self) -> "SlabIncrements":
        if self.increments is None:
            self.increments = SlabIncrements(self)
        return self.increments

    def solve_transpose(self, rhs: np.ndarray) -> np.ndarray:
        return np.array(rhs, dtype=float).reshape(-1)

    def transpose_partials(self, lam: np.ndarray):
        """``({"u": -M_u^T lam}, -M_rho^T lam)``."""
        u_bar, rho_bar = self.vjp(lam)
        return {"u": -u_bar}, -rho_bar

    def vjp(self, x_bar: np.ndarray):
        """``(u_bar (2n,), rho_bar (E,))`` for ``x_bar`` (2n,) on the moved mesh."""
        motion = self.mover.motion
        t_bar, f_bar, s_bar = self.derivatives().vjp(x_bar)
        return motion.target_transpose(t_bar), motion.density_transpose(self.rho, s_bar, f_bar)

    def jvp(self, u_dot: np.ndarray) -> np.ndarray:
        """``x_dot`` (2n,) for a change ``u_dot`` (2n,) of the structure's motion, ``rho`` held."""
        return self.derivatives().jvp(self.mover.motion.target(u_dot).reshape(-1))


class SlabIncrements:
    """What the tangent and reverse sweeps of one move need of its increments, each rank its
    quads' share (:func:`movers.incremental.increments_jvp`, ``increments_vjp``): per increment
    ``k`` the change ``dx_k``, the element forces ``K0_e dx_e (E_r, 8)``, the rows ``W f K0_e`` of
    the quads with a fixed dof, the blocks ``W f D_k (E_r, 8, 8)`` of the forces' shape
    derivative (``k > 0``) and, blended, ``K_k dx_k`` (2n,, summed over ranks)."""

    def __init__(self, lin: SlabMoveLinearization):
        m, d = lin.mover, lin.design
        self.lin, self.m, self.d = lin, m, d
        f = d.slab.stiffening
        scale = f[:, None, None] * d.weight[m.dofs][:, :, None]       # rows of f_e W
        self.edge = np.flatnonzero(m.is_fixed[m.dofs].any(axis=1))
        self.dofs_edge = m.dofs[self.edge]
        self.dx, self.forces, self.WK_edge, self.WD, self.Kdx = [], [], [], [], []
        self.fractions, self.a = schedule(lin.kernel, len(lin.states) - 1)   # h_k, a_k
        self.points = stiffness_points(lin.states, self.a)             # y_k
        for k, y_k in enumerate(self.points):
            dx = lin.states[k + 1] - lin.states[k]
            Xe = d.slab.points[m.quads] + y_k.reshape(-1, 2)[m.quads]
            K0 = lin.kernel(Xe)
            dx_e = dx[m.dofs]
            forces = np.einsum("eab,eb->ea", K0, dx_e)
            self.dx.append(dx)
            self.forces.append(forces)
            self.WK_edge.append((scale * K0)[self.edge])
            self.WD.append(scale * lin.kernel.force_derivative(Xe, dx_e) if k > 0 else None)   # x_0 = 0
            self.Kdx.append(None if d.blend is None else
                            m.allsum(assemble_vector(m.dofs, f[:, None] * forces, dx.size)))

    def solve(self, k: int, b: np.ndarray, transpose: bool) -> np.ndarray:
        """``A_k^-1 b`` (or ``A_k^-T b``) with the exact factors of this move's ``A_k`` (its matrix
        assembled again first where a later move has used it since)."""
        m, lin = self.m, self.lin
        matrix = m.matrices[k]
        if m.owners[k] != lin.token:
            m.system(self.d, lin.kernel, self.points[k], lin.target / m.n, matrix)
            m.owners[k] = lin.token
        return matrix.solve(b, transpose=transpose)        # exact: refactorized unless fresh

    def edge_apply(self, k: int, v: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``W K_k v`` (or ``K_k^T W v``) from the quads with a fixed dof, summed over ranks."""
        return self.m.allsum(element_apply(self.WK_edge[k], v, self.dofs_edge, transpose))

    def shape_apply(self, k: int, v: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``P_f W f D_k v`` (or its transpose's product with ``v`` zero on the fixed dofs)."""
        r = self.m.allsum(element_apply(self.WD[k], v, self.m.dofs, transpose))
        if not transpose:
            r[self.m.fixed] = 0.0
        return r

    def jvp(self, t_dot: np.ndarray) -> np.ndarray:
        """Tangent sweep: ``x_dot`` (2n,) along the change ``t_dot`` (2n,) of the target."""
        m, d = self.m, self.d
        t_dot = np.asarray(t_dot, dtype=float).reshape(-1)
        moved = bool(np.any(t_dot[m.fixed]))
        x_dot = x_dot_before = np.zeros_like(t_dot)
        for k in range(m.n):
            step, a = self.fractions[k] * t_dot, self.a[k]             # d_dot and a_k of increment k
            rhs = d.diag * step                                        # S_c d_dot
            if moved:
                rhs -= self.edge_apply(k, np.where(m.is_fixed, step, 0.0))
            if self.WD[k] is not None:                   # y_dot_k = x_dot_k + a_k (x_dot_k - x_dot_(k-1))
                rhs -= self.shape_apply(k, x_dot + a * (x_dot - x_dot_before) if a else x_dot)
            rhs[m.fixed] = step[m.fixed]
            dx = self.solve(k, rhs, False)
            dx[m.fixed] = step[m.fixed]
            x_dot_before, x_dot = x_dot, x_dot + dx
        return x_dot

    def vjp(self, x_bar: np.ndarray):
        """Reverse sweep: ``(target_bar (2n,), stiffening_bar (moving quads,), blend_bar (n,))``."""
        m, d, lin = self.m, self.d, self.lin
        x_bar = np.array(x_bar, dtype=float).reshape(-1)
        target_bar = np.zeros_like(x_bar)
        f_slab = np.zeros(len(m.quads))
        s_bar = np.zeros(x_bar.size // 2)
        carry = 0.0                                      # carry: increment k+1's share of x_k's adjoint
        for k in range(m.n - 1, -1, -1):
            a, h = self.a[k], self.fractions[k]
            b = x_bar.copy()
            b[m.fixed] = 0.0
            lam = self.solve(k, b, True)
            lam[m.fixed] = 0.0
            step_bar = np.zeros_like(x_bar)              # increment k's d_bar (d = h_k target)
            step_bar[m.fixed] = x_bar[m.fixed] - self.edge_apply(k, lam, transpose=True)[m.fixed]
            if d.blend is not None:                      # the increment's D = W K dx + S_c (dx - d)
                t_blend, s_part = d.blend.partials(lam, self.dx[k], h * lin.target, self.Kdx[k])
                step_bar -= t_blend
                s_bar -= s_part
            target_bar += h * step_bar
            f_slab -= np.einsum("ea,ea->e", (d.weight * lam)[m.dofs], self.forces[k])
            y_bar = None if self.WD[k] is None else -self.shape_apply(k, lam, transpose=True)  # d/dy_k [...]
            x_bar = x_bar + carry                        # y_k = (1 + a_k) x_k - a_k x_(k-1)
            carry = 0.0
            if y_bar is not None:
                x_bar = x_bar + (1 + a) * y_bar if a else x_bar + y_bar
                carry = -a * y_bar if a else 0.0
        f_bar = np.zeros(len(m.motion.base.quads))
        f_bar[m.local] = f_slab
        return target_bar, m.allsum(f_bar), s_bar
