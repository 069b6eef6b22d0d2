"""Continuation: a coupled solve carried to a state its warm start cannot reach directly.

A soft structure under the full flow may move so far that the coupled Newton
from its warm start does not converge, or the mesh mover meets a predictor
that folds an element. The solve always begins at the problem itself (the
full inflow, from the warm start: the previous design's state, or the state
the previous one-way stage left), and continues along a path only when that
fails. From a state of the one-way problem (no mesh motion yet) that first
attempt is *direct*: its sweep solves each block without the block's own
continuation (a finite-strain structure's load steps: ``direct`` of
:meth:`~tofsi.core.blocks.FieldBlock.solve`), so that a start the full inflow
cannot reach fails after one Newton of the structure instead of after its
load steps and the mover's cutbacks, only for the ramp below to begin anyway
(the large scene's first two-way solve at 80 x 40: the structure's Newton
alone, where before it was followed by its load steps with 2 cutbacks and
then the mover's 16 cutbacks; benchmarks/README.md), and that Newton stops
as soon as its residual has not halved in 5 iterations (5 there, not 25);
a structure stiff enough to need no ramp converges by that Newton alone. The path is one of two parameters:

* **the densities**, when the warm start is a converged state of the coupled
  problem at other densities (the previous design of an optimization, also
  across a stage whose projection is sharper): the densities go
  ``rho_t = (1 - t) rho_guess + t rho`` from ``t = 0`` (the warm start's own,
  where it is a solution) to ``t = 1``. Each step is a design change like an
  optimizer's, solved from the last step's state. A design this path cannot
  reach from a solved neighbour fails after a few short steps (an optimizer's
  trial design then falls back, a stage's first design is bridged:
  :mod:`tofsi.optimization.optimize`): an inflow ramp from rest, which throws
  the neighbour's state away, failed on every such design of the large scene
  as well, after 24 s more (80 x 40);
* **the inflow**, otherwise (a warm start of the one-way problem): the flow's
  prescribed boundary velocities scaled by ``lambda`` (``Continuation.load``;
  the structure's load and the mesh motion follow), from rest (the state at
  ``lambda = 0``) to the full inflow, the first step to half of it, since a
  state the full inflow's Newton cannot reach from its warm start is at least
  that far from it. Each step's flow starts from the secant through the last two
  states (from rest: the last one scaled), which holds the step's own inflow (the
  prescribed velocities are linear in ``lambda``); the first step's, where the failed
  attempt at the full inflow solved the flow before its structure failed (its sweep's
  ``solved``), from that flow scaled by ``lambda``: the step's sweep then needs no flow
  Newton step and no flow factorization (the large scene at 80 x 40: the flow's scaled
  residual 6e-3 there against the sweep's 1e-2; from rest one Newton step and an LU). From the last state unchanged,
  a Newton step, whose flow matrix eliminates the Dirichlet columns, would move the
  inflow alone and not the flow behind it: the large scene's step from half its
  inflow to all of it took 14 Newton iterations at 80 x 40, 10 from the secant. The
  structure and the mesh start where the last step left them (their secant
  inverts elements there).

Each step starts from the last converged one. A step of the inflow ramp short
of its end is solved only to ``STEP_TOL`` (the largest scaled residual of the
coupled Newton, not the problem's ``coupled.tol``): its state is the next step's
start and nothing else, and the Newton's last, quadratic steps to 1e-9 there
were thrown away (the large scene's step to half its inflow at 80 x 40: 4 Newton
steps, not 9; the step to the full inflow from there takes as many as before,
benchmarks/README.md); the ramp's steps are solved as load steps
(``load_step``: :mod:`tofsi.coupling.monolithic` refactorizes the preconditioner's
small blocks far from the solution). The densities' steps are solved as design
changes, each to the problem's tolerance. A converged step grows the
next by ``GROWTH``, a failed one is cut back to half, down to
``coupled.min_load_step`` (the inflow) or ``MIN_DENSITY_STEP`` (the
densities). Steps and cutbacks go to the state's report (``load_ramp`` or
``density_ramp``) and the log (``-v``); the converged state is the problem's
own (the caller's densities, at the full load and the caller's continuation
record), so its adjoint and every kept value are those of the problem. When
the inflow ramp fails after a direct attempt, the full inflow is tried once
more from the one-way state with the blocks' own continuation (the route the
direct attempt skips to fail fast) before the ramp's failure is raised.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Callable

import numpy as np

from tofsi.core.blocks import Continuation, State
from tofsi.core.errors import NumericalError

log = logging.getLogger(__name__)
FIRST_STEP = 0.5           # the inflow ramp's first step, from rest
FIRST_DENSITY_STEP = 0.5   # the densities' first step, from the warm start's
MIN_DENSITY_STEP = 0.25    # the densities' smallest step: a trial design the path cannot reach fails after two tries
GROWTH = 1.5               # a converged step's successor is this much longer (at most to the end)
STEP_TOL = 1e-2            # the largest scaled residual a step short of the path's end is solved to

Solve = Callable[..., State]      # (params, guess, rho, direct=False, tol=None, load_step=False) -> State


def ramped(solve: Solve, params: Continuation, guess: State | None, min_step: float, rho: np.ndarray,
           fields: tuple[str, ...] = (), inflow_fields: tuple[str, ...] = ()) -> State:
    """``solve(params, guess, rho)`` at the full load (``direct=True`` from a guess that holds
    some of ``fields`` but not all: a one-way state), or, when that fails, along a path in the
    densities (a ``guess`` holding every field of ``fields`` at other densities) or else in the
    inflow, each step's ``inflow_fields`` (the flow, whose prescribed values the load scales)
    from the secant (see the module docstring). Raises :class:`NumericalError` naming how far
    the path got when its step below the smallest (``min_step`` for the inflow) still fails."""
    try:
        if _partial(guess, fields):
            return solve(params, guess, rho, direct=True)
        return solve(params, guess, rho)
    except NumericalError as direct:
        first_failure = str(direct)     # the message only: the exception's traceback would hold
                                        # this frame (a cycle keeping the failed attempt's states)
        reached = {name: value for name, value in direct.solved.items() if name in inflow_fields}
    if _solved_elsewhere(guess, fields, rho):
        log.info("coupled solve failed from the previous design's state (%s); continuing in the densities "
                 "from that design's", first_failure)
        rho0 = np.asarray(guess.rho, dtype=float)
        state, report = _continue(lambda t, start, tol: solve(params, start, (1.0 - t) * rho0 + t * rho),
                                  guess, FIRST_DENSITY_STEP, MIN_DENSITY_STEP,
                                  "continuation in the densities from the previous design's")
        state.reports["density_ramp"] = {**report, "full_load_failure": first_failure}
        return state
    log.info("coupled solve failed at the full load (%s); ramping the inflow from rest", first_failure)
    try:
        state, report = _continue(lambda t, start, tol: solve(dataclasses.replace(params, load=params.load * t),
                                                               start, rho, tol=tol, load_step=True),
                                  None, FIRST_STEP, min_step, "inflow ramp",
                                  predict=lambda path, t: (secant(path, t, inflow_fields) if len(path) > 1
                                                           else from_full(reached, t, rho)))
    except NumericalError as err:
        failure = NumericalError(
            f"load continuation stopped at {err.diagnostic['reached']:.4g} of the inflow (a step of "
            f"{err.diagnostic['step']:.3g} to {err.diagnostic['failed']:.4g} failed: {err.__cause__})",
            {**err.diagnostic, "load": err.diagnostic["reached"], "failed_load": err.diagnostic["failed"],
             "load_steps": err.diagnostic["steps"], "full_load_failure": first_failure},
            state=err.state)
        failure.accepted = err.accepted
        if not _partial(guess, fields):
            raise failure from err.__cause__
        state = _with_own_continuation(solve, params, guess, rho, failure, err.__cause__)
        state.reports["load_ramp"] = {"steps": [], "cutbacks": 0, "full_load_failure": first_failure,
                                      "ramp_failure": str(failure), "own_continuation": True}
        return state
    state.reports["load_ramp"] = {**report, "full_load_failure": first_failure}
    return state


def _with_own_continuation(solve: Solve, params: Continuation, guess: State, rho, ramp_failure: NumericalError,
                           cause: BaseException | None) -> State:
    """The last resort of a first two-way solve whose direct attempt and inflow ramp both failed:
    the full inflow from the one-way state with the blocks' own continuation (a finite-strain
    structure's load steps, the mover's cutbacks), which the direct attempt skipped. Raises
    ``ramp_failure`` (the ramp's account, the more telling one; from ``cause``, its failed step's
    error) when this fails too."""
    log.info("%s; the full inflow with the blocks' own continuation", ramp_failure)
    try:
        return solve(params, guess, rho)
    except NumericalError as err:
        ramp_failure.diagnostic["own_continuation_failure"] = str(err)
        raise ramp_failure from cause


def _partial(guess: State | None, fields) -> bool:
    """``guess`` holds some of ``fields`` but not every one (a state of the one-way problem)."""
    held = [guess.fields.get(name) is not None for name in fields] if guess is not None else []
    return any(held) and not all(held)


def secant(path: list, t: float, names: tuple[str, ...]) -> State | None:
    """The start of the step to ``t`` from the states along the ``path`` (``(t_k, state)``, from
    ``(0, None)``: rest, every field zero): the fields ``names`` on the secant
    ``z_k + (t - t_k) / (t_k - t_(k-1)) (z_k - z_(k-1))`` (after the first step: ``z_1 t / t_1``),
    the others at ``z_k``; None from rest (the step's sweep fills every field). It keeps the last
    state's coupled linearizations (``coupled``: a load step's Newton starts from their solver)."""
    (t1, last) = path[-1]
    if last is None:
        return None
    t0, before = path[-2] if len(path) > 1 else (0.0, None)
    r = (t - t1) / (t1 - t0)
    fields = dict(last.fields)
    for name in names:
        if fields.get(name) is not None:
            fields[name] = fields[name] + r * (fields[name] - (0.0 if before is None else before.fields[name]))
    return State(rho=last.rho, fields=fields, params=last.params, stage=last.stage, coupled=last.coupled)


def from_full(reached: dict, t: float, rho) -> State | None:
    """The start of the inflow ramp's first step, to ``t``: the fields the failed attempt at
    the full inflow solved before it failed (``reached``: the inflow fields, the flow on the
    mesh at rest) scaled by ``t``, the secant from rest through them, whose prescribed values
    are the step's own; the others none (the step's sweep solves them). None from none: rest."""
    if not reached:
        return None
    return State(rho=rho, fields={name: t * value for name, value in reached.items()})


def _solved_elsewhere(guess: State | None, fields, rho) -> bool:
    """``guess`` is a converged state of every field of the coupled problem at other densities."""
    return (guess is not None and guess.rho is not None and bool(fields)
            and all(guess.fields.get(name) is not None for name in fields)
            and np.shape(guess.rho) == np.shape(rho) and not np.array_equal(guess.rho, rho))


def _continue(step_solve, start: State | None, first: float, min_step: float, what: str, predict=None):
    """Solve ``step_solve(t, start, tol)`` for ``t`` from 0 (``start``, which may be None: rest) to 1
    in adaptive steps, each from the last converged state (``predict(path, t)``: from the states so
    far, ``[(t_k, state)]``), those short of 1 with ``tol = STEP_TOL`` (at 1: None, the problem's own
    tolerance; ``step_solve`` may ignore it); ``(state at t = 1, {"steps", "cutbacks"})`` or a
    NumericalError whose
    diagnostic says how far it got (``reached``, ``failed``, ``step``, ``steps``, ``cutbacks``) and
    whose cause is the failed step's error."""
    steps, cutbacks = [], 0
    t, step, state = 0.0, first, start
    path = [(0.0, start)]
    while t < 1.0:
        trial = min(1.0, t + step)
        try:
            state = step_solve(trial, predict(path, trial) if predict else state,
                               None if trial >= 1.0 else STEP_TOL)
        except NumericalError as err:
            cutbacks += 1
            step *= 0.5
            log.info("%s: the step to %.4g of the way failed (%s); cut back to %.4g", what, trial, err, step)
            if step < min_step:
                failure = NumericalError(f"{what} stopped at {t:.4g} of the way (a step to {trial:.4g} failed: "
                                         f"{err})", {**err.diagnostic, "reached": t, "failed": trial,
                                                     "step": 2 * step, "steps": steps, "cutbacks": cutbacks},
                                         state=err.state)
                failure.accepted = state            # the last converged state (None: none), for its quality
                raise failure from err
            continue
        t = trial
        steps.append(t)
        path.append((t, state))
        log.info("%s: step %d, %.4g of the way, converged", what, len(steps), t)
        step = min(GROWTH * step, 1.0)
    return state, {"steps": steps, "cutbacks": cutbacks}
