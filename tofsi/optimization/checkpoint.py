"""The optimizer's checkpoint: every evaluation of the running stage and the last coupled state.

NLopt's MMA keeps internal state that cannot be saved, so a resume restarts
the stage from its first design and replays its evaluations bit for bit
(NLopt is deterministic given the same values). The checkpoint therefore
holds, per evaluation of the stage in order, the design and either what the
optimizer was told (objective, constraints, gradients, volume, mesh quality,
load-ramp counts: an :class:`~tofsi.optimization.protocol.Evaluation`) or, for a trial
design whose solve failed, the failure (a ``FailedEvaluation``, so
the replay falls back exactly where the run did); the history so far; the
stage's start and scale; the last coupled state's fields (the next solve's
warm start); the key of the block factors the next two-way solve starts from
(:mod:`tofsi.optimization.carried_factors`: what they were factorized from, so
a resume makes them again bitwise); and the problem's identity
(:func:`tofsi.optimization.resume.identity`).
Written atomically after every computed evaluation; read back into the
running stage a resume restarts (:func:`resume_stage`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace

import numpy as np

from tofsi.core.blocks import Continuation, Stage, State
from tofsi.coupling.coupled import continuation
from tofsi.optimization.history import Iteration
from tofsi.optimization.protocol import Evaluation, FailedEvaluation
from tofsi.optimization.stages import StageRun
from tofsi.runs.output import atomic_write, to_json
from tofsi.optimization.resume import check_resume, identity, read_checkpoint

SUCCESS_ARRAYS = ("gamma", "df", "g", "dg")


def write_checkpoint(path, problem, run, history, state: State) -> None:
    """The running stage ``run`` (:class:`tofsi.optimization.stages.StageRun`), the ``history`` rows and the
    last computed ``state`` of ``problem`` into ``path``."""
    arrays, failures = {}, {}
    for k, e in enumerate(run.log):
        arrays[f"e{k}_gamma"] = e.gamma
        if e.failed:
            failures[str(k)] = {"error": e.error, "diagnostic": json.loads(to_json(e.diagnostic))}
            continue
        for key in SUCCESS_ARRAYS[1:]:
            arrays[f"e{k}_{key}"] = getattr(e, key)
        arrays[f"e{k}_f"] = np.array([e.f, e.volume])
        if np.all(np.isfinite(e.quality)):             # NaN: the mesh did not move (left out)
            arrays[f"e{k}_quality"] = np.array(e.quality)
        arrays[f"e{k}_ramp"] = np.array(e.ramp)
    fields = {f"state_{k}": v for k, v in state.fields.items() if v is not None}
    carried = problem.factors.record() if problem.factors is not None else None
    if carried is not None:
        arrays.update(carried[1])
    meta = {"scene": problem.scene.name, "stage": run.stage, "n_stage_evaluations": len(run.log),
            "scale": run.scale, "history": [h.row() for h in history], "stage_start": run.start.tolist(),
            "failures": failures, "fallbacks_at_start": run.fallbacks_at_start,
            "params": record(run.record), "pending": [record(r) for r in run.pending],
            "previous": record(run.previous),
            "factors": None if carried is None else {**carried[0], "stage": record(problem.factors.stage)},
            "identity": identity(problem.scene, problem.model.mesh, problem.n_design)}

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), rho=state.rho, **fields, **arrays)
    atomic_write(path, write)


def quality_record(values) -> tuple:
    """An evaluation's mesh figures (see :func:`tofsi.optimization.problem.mesh_quality`), NaN for
    those a checkpoint of an earlier version did not hold."""
    values = [float(q) for q in values]
    return tuple(values + [np.nan] * (4 - len(values)))


def record(stage: Stage | None) -> dict | None:
    """A stage record (:class:`tofsi.core.blocks.Stage`) as JSON: its numbers and its structure,
    one flat table (None stays None)."""
    return None if stage is None else {**asdict(stage.params), "coupling": stage.coupling,
                                       "material": stage.material}


def stage_record(table: dict | None) -> Stage | None:
    """The stage of a :func:`record` (and of a checkpoint written before the numbers and the
    structure were two records: its ``structure_model`` is the material)."""
    if table is None:
        return None
    table = dict(table)
    structure = {"coupling": table.pop("coupling", ""),
                 "material": table.pop("material", "") or table.pop("structure_model", "")}
    table.pop("structure_model", None)
    return Stage(Continuation(**table), **structure)


def read_stage(path, problem) -> tuple[dict, list[Evaluation | FailedEvaluation], State]:
    """``(meta, evaluations to replay, last state)`` of the checkpoint at ``path``, checked
    against ``problem`` (same scene and mesh, or :class:`~tofsi.core.errors.InputError`)."""
    meta, data = read_checkpoint(path)
    check_resume(meta, data, problem, path)
    failures = meta.get("failures", {})
    replay = []
    for k in range(meta["n_stage_evaluations"]):
        gamma = data[f"e{k}_gamma"]
        if str(k) in failures:
            replay.append(FailedEvaluation(gamma, failures[str(k)]["error"], failures[str(k)]["diagnostic"]))
            continue
        f, volume = data[f"e{k}_f"]
        replay.append(Evaluation(gamma, float(f), data[f"e{k}_df"], data[f"e{k}_g"], data[f"e{k}_dg"],
                                 float(volume), quality_record(data.get(f"e{k}_quality", [])),
                                 tuple(int(r) for r in data.get(f"e{k}_ramp", [0, 0]))))
    state = State(rho=data["rho"], converged=True,
                  fields={k[len("state_"):]: v for k, v in data.items() if k.startswith("state_")})
    return meta, replay, state


def read_factors(path, problem) -> tuple[dict | None, dict, Stage | None]:
    """The checkpoint's key of the carried block factors: ``(table, arrays, stage)``, or
    ``(None, {}, None)`` where it holds none (checked as :func:`read_stage` checks)."""
    meta, data = read_checkpoint(path)
    check_resume(meta, data, problem, path)
    table = meta.get("factors")
    if table is None:
        return None, {}, None
    return table, {k: v for k, v in data.items() if k.startswith("factors")}, stage_record(table["stage"])


def resume_stage(path, problem) -> tuple[list[Iteration], int, StageRun, State]:
    """What a resume from the checkpoint at ``path`` restarts with: the history rows before
    the running stage's, the run's fallbacks before the stage, the stage as a
    :class:`~tofsi.optimization.stages.StageRun` whose evaluations are to be replayed (each
    successful one with its recorded time; the last with the checkpoint's state, so its
    evaluation is written again) and that last state (the next solve's warm start).
    Checked against ``problem`` as :func:`read_stage` checks."""
    meta, replay, state = read_stage(path, problem)
    succeeded = [k for k, e in enumerate(replay) if not e.failed]
    skip = meta["history"][-1]["iteration"] + 1 - len(succeeded)
    history = [Iteration.from_row(h) for h in meta["history"][:skip]]
    for k, row in zip(succeeded, meta["history"][skip:], strict=True):
        replay[k] = replace(replay[k], time_s=row["time_s"])
    if succeeded:                  # the last one's state is the checkpoint's: its evaluation
        replay[succeeded[-1]] = replace(replay[succeeded[-1]], state=state)   # is written again
    fallbacks = meta.get("fallbacks_at_start", 0)       # the stage's own are replayed
    stage, scene = meta["stage"], problem.scene
    run = StageRun(stage, np.asarray(meta["stage_start"], dtype=float), meta["scale"], replay=replay,
                   fallbacks_at_start=fallbacks, first_row=skip,
                   record=stage_record(meta.get("params")) or continuation(scene, stage),
                   pending=[stage_record(r) for r in meta.get("pending", [])],
                   previous=stage_record(meta.get("previous")) or (continuation(scene, stage - 1)
                                                                   if stage else None))
    return history, fallbacks, run, state
