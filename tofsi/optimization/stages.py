"""The continuation stages of an optimization run: the running stage's record and the bridges.

A stage is a :class:`~tofsi.core.blocks.Continuation` record (projection beta, SIMP
penalty, Brinkman q, coupling, structure model) that NLopt (or OC) runs for a
budget of evaluations. When a stage's first design fails there is no good design
of that stage to fall back to; the optimizer then steps back in the
continuation and first runs a *bridging stage* halfway from the previous
record (:func:`bridge`), recorded in :class:`StageRun` (``params``, ``pending``,
``previous``) so that a checkpoint inside a bridge resumes exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from tofsi.core.blocks import Continuation
from tofsi.core.errors import NumericalError


class StageStartFailed(Exception):
    """A stage's first design failed: no good design of the stage to fall back to (``error``)."""

    def __init__(self, error: NumericalError):
        super().__init__(str(error))
        self.error = error


CONTINUED = ("beta", "penalty", "brinkman_q")     # the parameters a bridging stage takes halfway


def bridge(previous: Continuation | None, target: Continuation) -> Continuation | None:
    """The stage record halfway from ``previous`` to ``target``: the geometric mean of each
    continued parameter that differs (the arithmetic one where either is 0), the rest as
    ``target``; None when there is nothing to bridge (no previous stage, or the two records
    differ by less than 5 % in every continued parameter)."""
    if previous is None:
        return None
    halfway = {}
    for name in CONTINUED:
        a, b = getattr(previous, name), getattr(target, name)
        if abs(b - a) > 0.05 * max(abs(a), abs(b)):
            halfway[name] = math.sqrt(a * b) if a > 0 and b > 0 else 0.5 * (a + b)
    return replace(target, **halfway) if halfway else None


@dataclass
class StageRun:
    """The running continuation stage: its number and start, the scale of its objective (its
    first value), its evaluations so far (checkpointed; failed trials too), the evaluations a
    resume replays, the last good evaluation (NLopt asks for the objective and the constraints
    at one point; a fallback returns to it) and the failures in a row."""

    stage: int
    start: np.ndarray
    scale: float | None = None
    log: list = field(default_factory=list)
    replay: list = field(default_factory=list)
    last: tuple | None = None                   # (gamma, entry) of the last good evaluation
    failures_in_a_row: int = 0
    fallbacks_at_start: int = 0                 # the run's fallbacks before the stage
    params: Continuation | None = None          # the record it runs with (a bridge's, or the stage's)
    pending: list = field(default_factory=list)  # records of this stage still to run after it (bridges)
    previous: Continuation | None = None        # the record of the stage (or bridge) before it
    first_row: int = 0                          # its first row in the history
