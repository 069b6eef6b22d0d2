"""Monolithic Newton over a cycle of field blocks (two-way coupling solved as one system).

Newton on the block Jacobian ``[[dR_a/dz_b]]`` of the cycle (every block of it
needs a residual form; kept as its blocks, :class:`~tofsi.linalg.BlockMatrix`),
with a backtracking line search on the largest block residual scaled by the
block's force scale. Each Newton step is solved inexactly, to the
Eisenstat-Walker relative tolerance (:func:`tofsi.core.iteration.forcing_term`;
convergence is judged on the true residual), by the system's linear solver
(:meth:`~tofsi.coupling.block_system.BlockSystem.linear_solver`: GMRES
preconditioned with block Gauss-Seidel over the fields' own factorizations, the
whole Jacobian's LU when GMRES fails, or the whole Jacobian's LU), kept for the
later iterates and the adjoint. With ``quasi_newton`` the couplings a block
marks as slow to build and slow to change (``FieldBlock.slow_couplings``: the
shape derivatives with respect to the mesh motion) are built at the first
iterate and kept while the Newton contracts (a step that leaves more than
``SLOW_CONTRACTION`` of the residual rebuilds them at its iterate); the
converged state's exact couplings are built once, for the adjoint
(:class:`CoupledLinearization`). In a step of the inflow ramp (``load_step``), couplings
rebuilt at such a far iterate are rebuilt once more at the first iterate whose merit fell
below ``NEAR_REBUILD`` of theirs: kept from far away they hold the Newton's tail to a
linear rate (the large scene's step to its full inflow at 160 x 80: 2.7e-3, 3.7e-4,
1.3e-5, 2.2e-7, 3.2e-9, 1.3e-10 with the couplings of an iterate at 0.42; 3.7e-4, 1.2e-5,
8e-9, 2.6e-11 with them rebuilt at 2.7e-3: one Newton step fewer, for one rebuild of the
shape derivatives; at 80 x 40 and 40 x 20, E = 1.5-3 kPa, as many). A Newton whose
residual falls by less than ``STALL_FACTOR`` in ``STALL_ITERATIONS`` steps stops early (a load step's
cutback is cheaper than its crawl); one that starts from a converged state of the cycle and is no
load step (a design change: the previous design's state, or the last step of the densities' path)
stops after ``DESIGN_STALL_ITERATIONS``: in the large example's whole optimization at 80 x 40 no
converging design change went more than 4 Newton steps without halving its residual, while the
failing trial designs' Newtons crawled 6-16 (their step lengths 1/8-1/128) until the line search
or the stall rule stopped them (8: twice the converging ones' worst); the two fallbacks' six failed
solves took 100 Newton iterates, 79 with this rule, the optimizer's path unchanged (at
160 x 80 every failed solve stopped by it, 303 s CPU against 396 s for the same end). A design
change's Newton also stops at its ``DESIGN_SHORT_STEPS``-th step that the line search cut to
``SHORT_STEP`` (1/16) of its length or less (a Newton direction good for a sliver of itself): over
the large example's whole optimization the converging design changes took at most one such step
(80 x 40; none at 160 x 80, whose shortest was 1/8), the failing ones 3-11 (160 x 80: 3-8), most
long before their stall window; with the rule the six failed solves take 47 Newton iterates, not
79 (80 x 40), 42, not 81 (160 x 80: the fallbacks 33 and 44 s CPU, not 54 and 61), the
optimizer's path unchanged (benchmarks/README.md). In a step of
the inflow ramp (``load_step``), after a Newton step that contracted by less than ``SLOW_CONTRACTION`` the block preconditioner's small
diagonal blocks are factorized at the iterate (the structure's and the mesh's; the flow's
factors are kept): the large scene's step to its full inflow at 80 x 40 took 83 GMRES
iterations over 11 Newton steps with the first iterate's factors, 36-38 with these. So are they
after a GMRES solve that took more iterations beyond a fresh preconditioner's than their
factorization costs (:func:`crept`; the preconditioner of the far iterates grown stale for the
near ones: at 160 x 80 the last five Newton steps to the full inflow took 12-18 GMRES iterations
each, 3-6 after it, and the adjoint found it fresh enough). Elsewhere
(a design change's solve, the densities' path) the rule is off: the Newton's path, though to the
same tolerance, then differs, and the large example's optimization, sensitive to it at a trial
design whose state snaps from 0.36 m to 0.22 m, ended elsewhere (1.98 or 1.62 J/m against 1.70).
A ramp's step after its first starts from the last step's solver (``recycled``: the block
preconditioner with its flow factors; at 80 x 40 the step to the full inflow makes no new flow
factorization, its Newton and GMRES counts as before). A solve looser than the settings' (a ramp's
step short of its end) that starts with a sweep (from rest) solves each block that takes a
tolerance (the flow, a finite-strain structure) to ``SWEEP_TOL`` of its force scale only: the
sweep only starts the Newton (at 80 x 40 from rest: 1 flow Newton step, not 3; 6 structure
steps, not 10; the monolithic Newton's 3 steps as before); so does the sweep of a direct attempt
(``direct``: from a one-way state, whose Newton goes on to the problem's tolerance, or fails and
leaves its flow to the inflow ramp; the large scene's flow there: 1 Newton step, not 2). It reports its history and raises
:class:`~tofsi.core.errors.NumericalError` when it does not converge.

The block system (:class:`~tofsi.coupling.block_system.BlockSystem`) gives the
blocks, the block Jacobian, the split of a stacked step and the linear solver;
this module holds the iteration alone.
"""

from __future__ import annotations

import logging

import numpy as np

from tofsi.core.errors import NumericalError
from tofsi.core.iteration import backtracking, forcing_term
from tofsi.coupling.jacobian_point import JacobianPoint
from tofsi.linalg import BlockGaussSeidel, BlockMatrix, RecyclingSolver

log = logging.getLogger(__name__)
EXACT_STEP = 1e-10       # the relative tolerance of a Newton step solved "exactly" (after a failed line search)
SLOW_CONTRACTION = 0.5   # a quasi-Newton step that leaves more than this of the merit rebuilds the kept couplings
STALL_ITERATIONS = 16    # a Newton whose merit fell by less than STALL_FACTOR over this many steps stops
STALL_FACTOR = 2.0
DESIGN_STALL_ITERATIONS = 8  # the same for a design change's Newton (from a converged state, no load step)
SHORT_STEP = 1.0 / 16    # a line search's accepted step this short: the Newton step's linear model failed far from its end
DESIGN_SHORT_STEPS = 3   # a design change's Newton stops at its this-many-th such step
NEAR_REBUILD = 1e-2      # a load step's slow couplings rebuilt far are rebuilt once more where the merit fell below this of theirs
SWEEP_TOL = 1e-2         # the scaled residual the starting sweep of a loose solve (a ramp's step) solves each block to


class CoupledLinearization:
    """The monolithic Jacobian of a cycle at its solution (``point``, a
    :class:`~tofsi.coupling.jacobian_point.JacobianPoint`) and the Newton's factorization."""

    def __init__(self, system, names: tuple[str, ...], lins: dict, solver, point=None):
        self.system, self.names, self.lins, self.solver, self.point = system, names, lins, solver, point
        self._J = None

    def matrix(self) -> BlockMatrix:
        if self._J is None:
            self._J = self.system.block_jacobian(self.lins, self.names, at=self.point)
        return self._J

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        return self.solver.solve_transpose(self.matrix(), b)


def solve_monolithic(system, comp, fields, state, direct: bool = False, tol: float | None = None,
                     load_step: bool = False, recycled=None) -> None:
    """Solve the cycle ``comp`` of the block ``system`` in place: ``fields`` (a guess, or none:
    one sweep first, ``direct``: without the blocks' own continuation) become the solution (to
    the largest scaled residual ``tol``, default the settings'), and ``state`` receives the
    blocks' linearizations, the cycle's :class:`CoupledLinearization` and the report ``"coupling"``.
    ``load_step``: a step of the inflow ramp, far from its solution (the small blocks refactorized
    after a step that contracted little, or whose GMRES took more iterations beyond a fresh
    preconditioner's than that refactorization costs, :func:`crept`); ``recycled``: the last load step's solver (or
    the previous design's), whose preconditioner starts this one's (a new one only when it goes stale)."""
    s = system.settings
    tol = s.tol if tol is None else tol
    rho, params = state.rho, state.params
    design_change = not load_step and all(fields[n] is not None for n in comp)   # from a converged state
    stall = DESIGN_STALL_ITERATIONS if design_change else STALL_ITERATIONS
    short_steps = 0                                 # a design change's accepted steps of at most SHORT_STEP
    system.start(comp, fields, state, direct=direct, tol=SWEEP_TOL if tol > s.tol or direct else None)
    solver = system.linear_solver(comp)
    if recycled is not None:
        solver = recycled.with_factorize(solver.factorize)
    blocks = [system.by_name[n] for n in comp]
    scales, history, kept = None, [], None

    def merit(values: dict, linearize: bool = False, bound: float = np.inf) -> tuple[float, dict | None]:
        return scaled_merit(blocks, scales, values, rho, params, linearize, bound)

    accepted = None                                 # the accepted full step's linearizations
    kept_at = None                                  # the merit of a far iterate whose slow couplings are kept
    for it in range(s.max_iter + 1):
        lins = accepted or {b.name: b.linearize(fields, rho, params) for b in blocks}
        R = [lins[b.name].residual for b in blocks]
        if scales is None:
            scales = [b.residual_scale(fields, rho, params, lins[b.name]) for b in blocks]
        norms = [float(np.linalg.norm(r)) / sc for r, sc in zip(R, scales, strict=True)]
        history.append({"iteration": it, **dict(zip(comp, norms, strict=True))})
        log.info("monolithic Newton %d: scaled residuals %s", it,
                 ", ".join(f"{n} {v:.2e}" for n, v in zip(comp, norms, strict=True)))
        if max(norms) <= tol:
            state.linearizations.update(lins)
            state.coupled[comp] = CoupledLinearization(system, comp, lins, solver,
                                                       JacobianPoint.at(rho, params, fields))
            state.reports["coupling"] = {"method": "monolithic", "history": history, "tol": tol}
            return
        if it == s.max_iter:
            break
        merits = [max(h[n] for n in comp) for h in history]
        if it >= stall and merits[-1] * STALL_FACTOR > merits[-1 - stall]:
            raise NumericalError(
                f"monolithic coupling stagnated: the largest scaled residual fell from "
                f"{merits[-1 - stall]:.3g} to {merits[-1]:.3g} in {stall} Newton steps",
                {"history": history})
        far = it > 0 and merits[-1] > SLOW_CONTRACTION * merits[-2]    # the last step contracted little
        near = bool(kept) and load_step and kept_at is not None and merits[-1] < NEAR_REBUILD * kept_at
        if kept and far:                                                 # kept ones gone stale
            log.info("monolithic Newton %d: the residual contracted by only %.2f; the slow couplings "
                     "of this iterate from here on", it, merits[-1] / merits[-2])
        elif near:                                                       # kept ones from far away
            log.info("monolithic Newton %d: the residual fell to %.2g of the iterate whose slow couplings "
                     "are kept; this iterate's from here on", it, merits[-1] / kept_at)
        if kept and (far or near):
            history[-1]["couplings_rebuilt"] = True
            kept = None
        if kept is None and s.quasi_newton:         # the slow couplings of the first iterate (or a later)
            kept = {(b.name, o): lins[b.name].coupling(o) for b in blocks
                    for o in getattr(b, "slow_couplings", ()) if o in comp}
            kept_at = None if near and not far else merits[-1]  # a load step rebuilds them once more near the solution
        b = -np.concatenate(R)
        eta = forcing_term(merits, tol)           # inexact Newton
        at = JacobianPoint.at(rho, params, fields)         # names the factors made of this iterate
        found, solver = newton_step(system, comp, lins, kept, b, eta, solver, fields, merit, max(norms),
                                    history, refactor=load_step and (far or crept(solver)), at=at)
        if found is None and (kept or eta > EXACT_STEP):  # not a descent direction: the exact one
            log.info("monolithic Newton %d: no decrease along the %s step; the exact Newton step "
                     "from here on", it, "quasi-Newton" if kept else "inexact")
            history[-1]["exact_step"] = True
            kept = {}                                      # the true couplings from here on
            found, solver = newton_step(system, comp, lins, kept, b, EXACT_STEP, solver, fields, merit,
                                        max(norms), history, at=at)
        if found is None:
            raise NumericalError("monolithic coupling: line search found no decrease",
                                 {"history": history})
        values, accepted = found[1]
        if found[0] < 1.0:
            log.info("monolithic Newton %d: step length %g", it, found[0])
        fields.update(values)
        short_steps += design_change and found[0] <= SHORT_STEP
        if short_steps >= DESIGN_SHORT_STEPS:
            raise NumericalError(
                f"monolithic coupling crawled: {short_steps} of {it + 1} Newton steps of a design change "
                f"were cut to at most {SHORT_STEP:g} of their length by the line search (the largest "
                f"scaled residual {merits[0]:.3g} at its start, {merits[-1]:.3g} before its last step)",
                {"history": history})
    raise NumericalError(f"monolithic coupling did not converge in {s.max_iter} Newton iterations",
                         {"history": history})


def scaled_merit(blocks, scales, values: dict, rho, params, linearize: bool = False,
                 bound: float = np.inf) -> tuple[float, dict | None]:
    """The largest residual norm of ``blocks`` at ``values``, each divided by its force scale
    (``scales``, in the blocks' order); with ``linearize`` read from the blocks' linearizations
    there (returned too, by name), so that the Jacobians of an accepted full step come from the
    same element passes as its residuals. First come the blocks smaller than the largest that
    read no larger block's field (the mesh motion, which reads the structure alone; not the
    structure, whose load would then be a flow pass of its own before the flow's linearization,
    which it otherwise shares), then the others in their order; as soon as one's scaled residual
    is at least ``bound`` (the merit a line search's trial must fall below) the others are skipped
    and that value is returned without linearizations: a full step the mesh's residual rejects
    costs no flow pass (the large scene's inflow ramp at 80 x 40: 2 of its 12 full steps). A
    non-finite residual gives ``inf``."""
    sizes = {b.name: b.size for b in blocks}
    largest = max(sizes.values())
    first = [i for i, b in sorted(enumerate(blocks), key=lambda ib: ib[1].size)
             if b.size < largest and all(sizes.get(o, 0) <= b.size for o in b.inputs)]
    lins_at, worst = ({} if linearize else None), 0.0
    for i in first + [i for i in range(len(blocks)) if i not in first]:
        b = blocks[i]
        if linearize:
            lins_at[b.name] = b.linearize(values, rho, params)
        r = lins_at[b.name].residual if linearize else b.residual(values, rho, params)
        value = float(np.linalg.norm(r)) / scales[i]
        if not np.isfinite(value):
            return np.inf, None
        worst = max(worst, value)
        if worst >= bound:
            return worst, None
    return worst, lins_at


def newton_step(system, comp, lins, kept, b, rtol, solver, fields, merit, norm, history, refactor=False,
                at=None):
    """One Newton step of the monolithic solve: the block Jacobian (with the ``kept`` couplings;
    ``at``: the iterate's :class:`~tofsi.coupling.jacobian_point.JacobianPoint`) solved to
    ``rtol`` (``refactor``: far from the solution, with the preconditioner's small blocks
    factorized at this iterate first), then the backtracking line search on the merit. Returns
    ``(the accepted fields or None, the solver)`` -- the whole Jacobian's LU when GMRES fails."""
    J = system.block_jacobian(lins, comp, kept, at=at)
    if refactor:
        refactor_small_blocks(solver, J, history)
    try:
        step = solver.solve(J, b, rtol=rtol)
    except NumericalError as err:             # block Gauss-Seidel too weak: the monolithic LU
        if not J.assembled:                   # a coupling known by its products only: none
            raise
        log.warning("monolithic Newton %d: %s; factorizing the whole Jacobian instead", len(history) - 1, err)
        history[-1]["fallback"] = "direct"
        solver = system.linear_solver(comp, "direct")
        step = solver.solve(J, b, rtol=rtol)
    dz = system.split(step, comp)

    def trial(alpha):                         # the full step linearized: the next iterate's
        values = dict(fields)
        values.update({n: fields[n] + alpha * dz[n] for n in comp})
        value, lins_at = merit(values, linearize=(alpha == 1.0), bound=norm)   # at least norm: rejected
        return value, (values, lins_at)
    found = backtracking(norm, trial)
    if found is not None:
        history[-1]["step_length"] = found[0]
    return found, solver


def crept(solver: RecyclingSolver) -> bool:
    """True when the solver's last GMRES solve took more iterations beyond a fresh block
    preconditioner's than refactorizing its small blocks costs (``refactor_iterations``)."""
    return solver.last_excess is not None and solver.last_excess > solver.solver.refactor_iterations


def refactor_small_blocks(solver, J: BlockMatrix, history: list) -> None:
    """A Newton step far from the solution (its predecessor contracted by less than
    ``SLOW_CONTRACTION``): the block Gauss-Seidel preconditioner the solver keeps gets its small
    diagonal blocks factorized at this iterate (:meth:`BlockGaussSeidel.refactor_small_blocks`:
    the structure's and the mesh's tangents move most there, the flow's factors are kept)."""
    pre = solver.solver
    if isinstance(pre, BlockGaussSeidel) and not solver.stale and pre.shape == J.shape:
        try:
            blocks = pre.refactor_small_blocks(J)
        except NumericalError:          # its released factors are gone: a whole new one (or its failure)
            solver.refresh(J)
            return
        history[-1]["small_blocks_refactorized"] = True
        log.info("monolithic Newton %d: the preconditioner's blocks %s factorized at this iterate",
                 len(history) - 1, blocks)
