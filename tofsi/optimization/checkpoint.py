"""The optimizer's checkpoint: every evaluation of the running stage and the last coupled state.

NLopt's MMA keeps internal state that cannot be saved, so a resume restarts
the stage from its first design and replays its evaluations bit for bit
(NLopt is deterministic given the same values). The checkpoint therefore
holds, per evaluation of the stage in order, the design and either what the
optimizer was told (objective, constraints, gradients, volume, mesh quality,
load-ramp counts) or, for a trial design whose solve failed, the failure (so
the replay falls back exactly where the run did); the history so far; the
stage's start and scale; the last coupled state's fields (the next solve's
warm start); and the problem's identity (:func:`tofsi.optimization.resume.identity`).
Written atomically after every computed evaluation.
"""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np

from tofsi.core.blocks import State
from tofsi.runs.output import atomic_write, to_json
from tofsi.optimization.resume import check_resume, identity, read_checkpoint

SUCCESS_ARRAYS = ("gamma", "df", "g", "dg")


def write_checkpoint(path, problem, run, history, state: State) -> None:
    """The running stage ``run`` (:class:`tofsi.optimization.stages.StageRun`), the ``history`` rows and the
    last computed ``state`` of ``problem`` into ``path``."""
    arrays, failures = {}, {}
    for k, e in enumerate(run.log):
        arrays[f"e{k}_gamma"] = e["gamma"]
        if e.get("failed"):
            failures[str(k)] = {"error": e["error"], "diagnostic": json.loads(to_json(e["diagnostic"]))}
            continue
        for key in SUCCESS_ARRAYS[1:]:
            arrays[f"e{k}_{key}"] = e[key]
        arrays[f"e{k}_f"] = np.array([e["f"], e["volume"]])
        arrays[f"e{k}_quality"] = np.array(e["quality"])
        arrays[f"e{k}_ramp"] = np.array(e["ramp"])
    fields = {f"state_{k}": v for k, v in state.fields.items() if v is not None}
    meta = {"scene": problem.scene.name, "stage": run.stage, "n_stage_evaluations": len(run.log),
            "scale": run.scale, "history": [asdict(h) for h in history], "stage_start": run.start.tolist(),
            "failures": failures, "fallbacks_at_start": run.fallbacks_at_start,
            "params": record(run.params), "pending": [record(r) for r in run.pending],
            "previous": record(run.previous),
            "identity": identity(problem.scene, problem.model.mesh, problem.n_design)}

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), rho=state.rho, **fields, **arrays)
    atomic_write(path, write)


def record(params) -> dict | None:
    """A stage record (:class:`tofsi.core.blocks.Continuation`) as JSON (None stays None)."""
    return None if params is None else asdict(params)


def read_stage(path, problem) -> tuple[dict, list[dict], State]:
    """``(meta, evaluations to replay, last state)`` of the checkpoint at ``path``, checked
    against ``problem`` (same scene and mesh, or :class:`~tofsi.core.errors.InputError`)."""
    meta, data = read_checkpoint(path)
    check_resume(meta, data, problem, path)
    failures = meta.get("failures", {})
    replay = []
    for k in range(meta["n_stage_evaluations"]):
        gamma = data[f"e{k}_gamma"]
        if str(k) in failures:
            replay.append({"gamma": gamma, "failed": True, **failures[str(k)]})
            continue
        f, volume = data[f"e{k}_f"]
        replay.append({"gamma": gamma, "df": data[f"e{k}_df"], "g": data[f"e{k}_g"], "dg": data[f"e{k}_dg"],
                       "f": float(f), "volume": float(volume),
                       "quality": tuple(float(q) for q in data.get(f"e{k}_quality", [np.nan] * 3)),
                       "ramp": tuple(int(r) for r in data.get(f"e{k}_ramp", [0, 0]))})
    state = State(rho=data["rho"], converged=True,
                  fields={k[len("state_"):]: v for k, v in data.items() if k.startswith("state_")})
    return meta, replay, state
