"""Load continuation: a coupled solve carried to large motion by ramping the inflow.

A soft structure under the full flow may move so far that the coupled Newton
from the previous design's state (or from rest) does not converge, or the
mesh mover meets a predictor that folds an element. The physical path goes
through the intermediate loads: with the flow's prescribed boundary
velocities scaled by ``lambda`` (``Continuation.load``; the structure's load
and the mesh motion follow), the solve goes

    lambda_0 = 0 (rest) -> lambda_1 -> ... -> lambda_K = 1,

each step warm-started from the last converged one, with adaptive steps:
a converged step grows the next by ``GROWTH``, a failed one is cut back to
half (and retried from the last converged state) down to
``coupled.min_load_step``. The ramp starts only when the direct solve at the
full load fails, so a solve that converges directly is unchanged. Its steps
and cutbacks go to the state's report (``load_ramp``) and the log (``-v``);
the converged state is the full-load one, at the caller's continuation
record, so its adjoint and every kept value are those of the problem.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Callable

from tofsi.core.blocks import Continuation, State
from tofsi.core.errors import NumericalError

log = logging.getLogger(__name__)
FIRST_STEP = 0.25          # the first ramp step, from rest
GROWTH = 1.5               # a converged step's successor is this much longer (at most to the full load)


def ramped(solve: Callable[[Continuation, State | None], State], params: Continuation, guess: State | None,
           min_step: float) -> State:
    """``solve(params, guess)`` at the full load (``params.load``), or, when that fails, along a
    ramp of the load from rest (see the module docstring). Raises :class:`NumericalError` naming the last
    converged load when a step below ``min_step`` still fails."""
    try:
        return solve(params, guess)
    except NumericalError as direct:
        first_failure = direct
    log.info("coupled solve failed at the full load (%s); ramping the inflow from rest", first_failure)
    steps, cutbacks = [], 0
    load, step, state = 0.0, FIRST_STEP, None               # fractions of the caller's load
    while load < 1.0:
        trial = min(1.0, load + step)
        try:
            state = solve(dataclasses.replace(params, load=params.load * trial), state)
        except NumericalError as err:
            cutbacks += 1
            step *= 0.5
            log.info("load step to %.4g failed (%s); cut back to %.4g", trial, err, step)
            if step < min_step:
                raise NumericalError(
                    f"load continuation stopped at {load:.4g} of the inflow (a step of {2 * step:.3g} to "
                    f"{trial:.4g} failed: {err})",
                    {**err.diagnostic, "load": load, "failed_load": trial, "load_steps": steps,
                     "cutbacks": cutbacks, "full_load_failure": str(first_failure)}, state=err.state) from err
            continue
        load = trial
        steps.append(load)
        log.info("load step %d: %.4g of the inflow converged", len(steps), load)
        step = min(GROWTH * step, 1.0)
    state.reports["load_ramp"] = {"steps": steps, "cutbacks": cutbacks, "full_load_failure": str(first_failure)}
    return state
