"""The final state of an optimization (``final_state.npz``): what re-solving its design needs.

The optimizer reaches a soft two-way design along a warm-start path: every
evaluation starts from the previous one's fields. A cold solve of the final
design starts from rest and ramps the inflow (:mod:`tofsi.load_ramp`); for a
large-motion design the ramp may stop short of the full inflow although the
state exists (the large-deformation example's design: at 0.12 of the
inflow). So ``tofsi optimize`` writes the final design's solved fields
beside ``design.npy``, with the continuation stage they were solved at, and
``tofsi solve --from RUN`` starts from them (taking RUN's design and stage
unless ``--design``/``--stage`` say otherwise): its figures are
``result.json``'s to the solver tolerance.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from tofsi.core.blocks import State
from tofsi.core.errors import InputError
from tofsi.runs.output import atomic_write
from tofsi.optimization.checkpoint import record, stage_record
from tofsi.optimization.resume import identity

FILE = "final_state.npz"


def write_final_state(path, problem, gamma: np.ndarray, state: State, stage: int) -> None:
    """``gamma``, its solved ``state`` (fields and densities) and the stage record into ``path``."""
    meta = {"scene": problem.scene.name, "stage": int(stage), "params": record(state.stage),
            "identity": identity(problem.scene, problem.model.mesh, problem.n_design)}
    fields = {f"state_{k}": v for k, v in state.fields.items() if v is not None}

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), gamma=gamma, rho=state.rho, **fields)
    atomic_write(path, write)


def read_final_state(run: Path, problem) -> tuple[dict, State]:
    """``(meta, state)`` of ``run``'s final state, its fields sized for ``problem``'s mesh and
    fields (else :class:`~tofsi.errors.InputError` naming ``--from``)."""
    run = Path(run)
    path = run / FILE
    if not run.is_dir():
        raise InputError("--from", str(run), "no such folder (give the --output folder of a tofsi optimize run)")
    if not path.is_file():
        raise InputError("--from", str(run), f"holds no {FILE}: a tofsi optimize run writes it when it "
                         "finishes (an interrupted run: finish it with --resume)")
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: np.array(npz[k], copy=True) for k in npz.files}
        meta = json.loads(str(data["meta"]))
        stage = stage_record(meta["params"])
    except (OSError, EOFError, KeyError, TypeError, ValueError, zipfile.BadZipFile) as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError("--from", str(run), f"{FILE} cannot be read ({reason})") from None
    mesh = problem.model.mesh
    here = identity(problem.scene, mesh, problem.n_design)["mesh"]
    recorded = meta.get("identity", {}).get("mesh")
    fields = {k[len("state_"):]: v for k, v in data.items() if k.startswith("state_")}
    sizes = {b.name: b.size for b in problem.model.system_for(stage).blocks}
    wrong = [k for k, v in fields.items() if k in sizes and v.shape != (sizes[k],)]
    if recorded != here or wrong or data["rho"].shape != (mesh.n_elements,):
        raise InputError("--from", str(run), f"its state is of another mesh ({recorded}; this scene's: {here})")
    return meta, State(rho=data["rho"], fields=fields, params=stage.params, converged=True,
                       stage=stage)
