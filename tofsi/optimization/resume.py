"""``--resume`` continues the same problem, or refuses with the keys that differ.

A checkpoint records the effective scene (every key, after ``--set``) and the
mesh's size (:func:`identity`). On resume :func:`check_resume` compares them
with the scene of the resuming run: a resume replays the stored evaluations,
so any key that can change the replayed history (the objective, the volume
bound, the filter, the continuation schedule, the physics, the mesh, the
stopping tolerances) must be equal. Only keys that cannot change it may
differ (each scene table's ``resumable`` keys, :func:`~tofsi.runs.provenance.resumable_keys`). A missing, truncated or garbage checkpoint, or
one of another mesh, is an :class:`~tofsi.core.errors.InputError` in one line.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from tofsi.core.errors import InputError
from tofsi.runs.provenance import differing_keys, flatten, resumable_keys, scene_tables

AFRESH = "start afresh with --overwrite or a new --output folder"


def identity(scene, mesh, n_design: int) -> dict:
    """What a checkpoint records about its problem (JSON)."""
    return {"scene": scene_tables(scene),
            "mesh": {"nx": int(mesh.nx), "ny": int(mesh.ny), "n_elements": int(mesh.n_elements),
                     "n_nodes": int(mesh.n_nodes), "n_design": int(n_design)}}


def read_checkpoint(path) -> tuple[dict, dict]:
    """``(meta, arrays)`` of a checkpoint; fresh, aligned array copies (vectorized kernels
    round by alignment, and a resume must be bitwise exact)."""
    path = Path(path)
    if path.is_dir() or not path.exists():
        raise InputError("--resume", str(path), "no checkpoint to resume from")
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: np.array(npz[k], copy=True) for k in npz.files}
        meta = json.loads(str(data["meta"]))
        if not isinstance(meta, dict):
            raise ValueError("its record is not a table")
    except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError("--resume", str(path), f"the checkpoint cannot be read ({reason}); {AFRESH}") from None
    return meta, data


def _shown(value) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def check_resume(meta: dict, data: dict, problem, path) -> None:
    """Raise :class:`InputError` unless the checkpoint is of ``problem``'s scene and mesh."""
    scene, mesh = problem.scene, problem.model.mesh
    if meta.get("scene") != scene.name:
        raise InputError("--resume", meta.get("scene"), f"the checkpoint is of another scene, not {scene.name}")
    recorded = meta.get("identity")
    if not isinstance(recorded, dict) or "scene" not in recorded or "mesh" not in recorded:
        raise InputError("--resume", str(path), "the checkpoint does not record its scene (an older "
                         f"tofsi wrote it), so the resume cannot be checked; {AFRESH}")
    old, new = flatten(recorded["scene"]), flatten(scene_tables(scene))
    may_differ = resumable_keys()
    differ = [k for k in differing_keys(recorded["scene"], scene_tables(scene)) if k not in may_differ]
    if differ:
        changes = "; ".join(f"{k}: {_shown(old.get(k))} -> {_shown(new.get(k))}" for k in differ[:4])
        more = f" and {len(differ) - 4} more" if len(differ) > 4 else ""
        raise InputError("--resume", differ, f"the scene differs from the checkpoint's ({changes}{more}); "
                         "a resume continues the same problem (only "
                         f"{', '.join(may_differ[1:])} may change); {AFRESH}")
    here = identity(scene, mesh, problem.n_design)["mesh"]
    sizes = {"rho": mesh.n_elements, **{k: problem.n_design for k in data if k.endswith("_gamma")}}
    wrong = [k for k, n in sizes.items() if k in data and data[k].shape != (n,)]
    if recorded["mesh"] != here or wrong:
        raise InputError("--resume", str(path), f"the checkpoint is of another mesh ({recorded['mesh']}, "
                         f"this scene's: {here}); {AFRESH}")
    done = len(meta.get("history", []))
    if scene.optimizer.max_iter < done:
        raise InputError("optimizer.max_iter", scene.optimizer.max_iter,
                         f"the checkpoint already holds {done} iterations; allowed: >= {done}")


def check_checkpoint(path, problem) -> None:
    """Read and check the checkpoint at ``path`` (before a resumed run writes anything)."""
    meta, data = read_checkpoint(path)
    check_resume(meta, data, problem, path)
