"""What the optimizer asks of a design problem, and the record of one evaluation.

:class:`~tofsi.optimization.optimize.Optimizer` drives any object of the
:class:`DesignProblem` protocol: the serial :class:`~tofsi.optimization.problem.Problem`
(every field of the scene, solved on one process) and the distributed flow
(:class:`tofsi.parallel.flow_problem.DistributedFlowProblem`, a flow-only
scene by slabs under ``mpiexec``, driven from rank 0). The optimizer asks for
the design at the start, sets each continuation stage, shifts a stage's start
into the volume bound, and evaluates designs; each evaluation is one
:class:`Evaluation` (what NLopt or OC is told, what the history row and the
checkpoint record), or a :class:`FailedEvaluation` where the solve failed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from tofsi.core.blocks import Stage, State

NO_QUALITY = (float("nan"),) * 4          # the mesh did not move: no quality to report


@dataclass(frozen=True, eq=False)
class Evaluation:
    """One evaluated design at one continuation stage.

    gamma : the design variables ``(n_design,)``; f, df : the objective and ``df/dgamma``
    ``(n_design,)``; g, dg : the constraints ``g <= 0`` ``(m,)`` (the volume bound first) and
    ``dg/dgamma`` ``(m, n_design)``; volume : the solid fraction of the design region;
    quality : ``(min skewness, min area change, max area change, max interface gap [m])`` of
    the moved fluid mesh (NaN where it did not move); ramp : ``(steps, cutbacks)`` of the inflow ramp the solve
    took (``(0, 0)``: none); state : the coupled state's record (fields, no factorizations;
    None for an evaluation replayed from a checkpoint, or once a newer one holds the state);
    time_s : the run time a replayed evaluation was recorded at (None: computed now).
    """

    gamma: np.ndarray
    f: float
    df: np.ndarray
    g: np.ndarray
    dg: np.ndarray
    volume: float
    quality: tuple[float, float, float, float] = NO_QUALITY
    ramp: tuple[int, int] = (0, 0)
    state: State | None = None
    time_s: float | None = None
    failed: ClassVar[bool] = False


@dataclass(frozen=True, eq=False)
class FailedEvaluation:
    """A trial design whose solve failed: the error's message and its diagnostic (checkpointed,
    so a resume falls back exactly where the run did)."""

    gamma: np.ndarray
    error: str
    diagnostic: dict
    failed: ClassVar[bool] = True


@runtime_checkable
class DesignProblem(Protocol):
    """A density-based design problem as the optimizer drives it.

    scene : the validated scene (its ``design`` and ``optimizer`` tables);
    model : the scene's serial model, read for the mesh, the fields' figures and pictures of a
        state (the optimizer never solves with it);
    map : the design map (filter and projection; ``map.design``: the design elements);
    objective : the registry objective it minimizes (its label and units);
    stage : the current continuation stage (:class:`~tofsi.core.blocks.Stage`);
    evaluations : the evaluations computed so far (solves, not kept ones);
    factors : what the next solve starts from besides its guess, recorded in the checkpoint
        (the serial problem's carried block factors,
        :class:`~tofsi.optimization.carried_factors.CarriedFactors`; None where there are none).
    """

    scene: Any
    model: Any
    map: Any
    objective: Any
    stage: Stage
    evaluations: int
    factors: Any

    @property
    def n_design(self) -> int: ...

    def initial_design(self) -> np.ndarray:
        """The run's first design ``(n_design,)``."""

    def set_stage(self, stage: Stage) -> None:
        """The continuation stage of the next evaluations."""

    def set_guess(self, state: State | None) -> None:
        """The state the next solve starts from (a resumed run's checkpointed state)."""

    def resume_factors(self, table: dict | None, arrays: dict, stage: Stage | None) -> None:
        """The factors the next solve starts from, made again from a checkpoint's record of
        them (:func:`tofsi.optimization.checkpoint.read_factors`; ``table`` None: none)."""

    def densities(self, gamma) -> np.ndarray:
        """The physical densities ``(E,)`` of ``gamma`` at the current stage (no solve)."""

    def phase_fraction(self, gamma) -> float:
        """The constrained phase's fraction of the design region (no solve)."""

    def feasible(self, gamma) -> np.ndarray:
        """``gamma``, shifted into the volume bound if it lies outside (no solve)."""

    def constraint_names(self) -> list[str]:
        """The names of the constraints at the current stage, in the order of ``g``."""

    def evaluation(self, gamma) -> Evaluation:
        """The evaluation of ``gamma`` at the current stage (the last one kept); raises
        :class:`~tofsi.core.errors.NumericalError` when the solve fails."""
