"""The output folder of a run: checked before any computation, never mixed with another run.

* :func:`check_writable` -- ``--output`` must be a folder tofsi can create
  and write: not a file, not under a file, not in ``/dev``, ``/proc`` or
  ``/sys``, not on a read-only or full filesystem. Checked by writing (and
  removing) a probe file in the nearest existing folder, which also catches
  what permission bits do not tell (read-only mounts, running as root).
* :class:`RunFolder` -- a fresh run refuses a folder that holds files
  (``--overwrite`` replaces the previous run, ``--resume`` continues it);
  the previous run's files are removed only when the new run writes its
  first file, so a run that stops on bad input leaves the folder as it was.
  Files that are not tofsi outputs are never removed.
* ``run.json`` -- the provenance of the run (:mod:`tofsi.provenance`),
  written when the run starts writing and completed when it ends.
"""

from __future__ import annotations

import fnmatch
import json
import logging
import os
import tempfile
from pathlib import Path

from tofsi.errors import InputError
from tofsi.output import write_json
from tofsi.provenance import now

log = logging.getLogger(__name__)

SYSTEM_FOLDERS = (Path("/dev"), Path("/proc"), Path("/sys"))
RUN_FILE = "run.json"
# Every name a tofsi command or example writes (a previous run's files without a run.json).
OUTPUT_PATTERNS = ("run.json", "diagnostic.json", "mesh.vtu", "mesh.png", "moved_mesh.*", "failed_mesh.*",
                   "move.json", "solve.json", "solution.vtu", "solution_*.png", "design_*.png",
                   "design_*.vtu", "design_series.pvd", "design.npy", "checkpoint.npz", "history.csv",
                   "history.json", "result.json", "convergence.png", "check_gradients.json",
                   "study.csv", "study.json", "study.png")


def check_writable(path, key: str = "--output") -> Path:
    """Raise :class:`InputError` unless ``path`` is, or can become, a writable folder."""
    shown = str(path)
    real = Path(os.path.abspath(path)).resolve()
    for system in SYSTEM_FOLDERS:
        if real == system or system in real.parents:
            raise InputError(key, shown, f"lies in the system folder {system}; choose a folder for results")
    if real.exists() and not real.is_dir():
        raise InputError(key, shown, "is a file, not a folder")
    existing = real
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(key, shown, f"lies under {existing}, which is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".tofsi-probe-")
        os.close(fd)
        os.remove(probe)
    except OSError as err:
        raise InputError(key, shown, f"cannot write in {existing} ({err.strerror or err})") from None
    return real


def visible_files(folder: Path) -> list[str]:
    """Names in ``folder`` that are not hidden (temporary files start with a dot)."""
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


def read_record(folder: Path) -> dict | None:
    """The ``run.json`` of the run in ``folder`` (None if absent or unreadable)."""
    try:
        record = json.loads((Path(folder) / RUN_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def describe(record: dict | None, names: list[str]) -> str:
    if record:
        when = record.get("finished") or record.get("started") or "an unknown time"
        status = record.get("status", "unknown")
        return f"the files of another run ({record.get('program', 'tofsi')}, {status}, {when})"
    return f"{len(names)} file(s) ({', '.join(names[:3])}{', ...' if len(names) > 3 else ''})"


class RunFolder:
    """The output folder of one run.

    program : how the run is named in ``run.json`` (``"tofsi optimize"``, an example's path)
    overwrite : replace a previous run's files (``--overwrite``)
    resume : continue the run in the folder (``--resume``; its files stay)
    replaces_own : a previous run of the same ``program`` is replaced without ``overwrite``
        (examples, whose folder is their own)
    """

    def __init__(self, path, program: str, overwrite: bool = False, resume: bool = False,
                 replaces_own: bool = False):
        self.path, self.program = Path(path), program
        self.overwrite, self.resume, self.replaces_own = overwrite, resume, replaces_own
        self.previous: dict | None = None
        self.foreign: set[str] = set()
        self.record: dict | None = None

    @property
    def begun(self) -> bool:
        return self.record is not None

    def check(self) -> "RunFolder":
        """Before any computation: writable, and not holding another run (unless asked)."""
        check_writable(self.path)
        names = visible_files(self.path)
        self.previous = read_record(self.path)
        listed = set((self.previous or {}).get("files", []))
        self.foreign = {n for n in names if n not in listed
                        and not any(fnmatch.fnmatch(n, p) for p in OUTPUT_PATTERNS)}
        own = (self.replaces_own and self.previous is not None
               and self.previous.get("program") == self.program)
        if names and not (self.overwrite or self.resume or own):
            raise InputError("--output", str(self.path),
                             f"holds {describe(self.previous, names)}; add --overwrite to replace "
                             "them, or choose a new --output folder")
        return self

    def begin(self, record: dict) -> None:
        """Before the first write: clear the previous run (unless resuming), write run.json."""
        if self.begun:
            return
        if not self.resume:
            self._clear()
        elif self.previous:
            record = {**record, "resumed_from": {k: self.previous.get(k) for k in
                                                 ("started", "finished", "exit_status", "stop_reason")}}
        if self.foreign:
            log.warning("%s: kept %d file(s) that are not tofsi outputs: %s", self.path,
                        len(self.foreign), ", ".join(sorted(self.foreign)[:5]))
        self.record = dict(record)
        write_json(self.path / RUN_FILE, self.record)

    def _clear(self) -> None:
        """Remove the previous run's files (run.json last: until then the folder is its)."""
        names = [n for n in visible_files(self.path) if n not in self.foreign]
        for name in sorted(names, key=lambda n: n == RUN_FILE):
            target = self.path / name
            if target.is_file() or target.is_symlink():
                target.unlink()
        if names:
            log.info("%s: removed %d file(s) of the previous run", self.path, len(names))

    def finish(self, exit_status: int, **extra) -> None:
        """Complete run.json: end time, exit status, status words, the files written."""
        if not self.begun:
            return
        status = {0: "finished", 1: "checks failed", 2: "bad input", 3: "numerical failure",
                  130: "interrupted", 143: "terminated"}.get(exit_status, "failed")
        files = [n for n in visible_files(self.path) if n not in self.foreign]
        self.record.update(finished=now(), exit_status=exit_status, status=status, files=files,
                           **{k: v for k, v in extra.items() if v is not None})
        write_json(self.path / RUN_FILE, self.record)
