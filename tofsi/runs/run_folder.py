"""The output folder of a run: checked before any computation, never mixed with another run.

* :func:`check_writable` -- ``--output`` must be a folder tofsi can create
  and write: not a file, not under a file, not in ``/dev``, ``/proc`` or
  ``/sys``, not on a read-only or full filesystem, with folder names the
  file system allows (length, no control characters) and room in the path
  for every file name a run writes. Checked by writing (and removing) a
  probe file in the nearest existing folder, which also catches what
  permission bits do not tell (read-only mounts, running as root).
* :class:`RunFolder` -- a fresh run refuses a folder that holds files
  (``--overwrite`` replaces the previous run, ``--resume`` continues it);
  the previous run's files are removed only when the new run writes its
  first file, so a run that stops on bad input leaves the folder as it was.
  Files that are not tofsi outputs are never removed. One run at a time:
  the folder is locked (:mod:`tofsi.runs.folder_lock`) from the check to the end
  of the run, so a second run into it is refused, naming the first.
* ``run.json`` -- the provenance of the run (:mod:`tofsi.runs.provenance`),
  written when the run starts writing and completed when it ends, also when
  a file could not be written (disk full): a small reserve file kept beside
  it from the start is removed first, so the record has room.
"""

from __future__ import annotations

import fnmatch
import json
import logging
import os
import tempfile
import unicodedata
from pathlib import Path

from tofsi.core.errors import InputError, WriteError
from tofsi.runs.folder_lock import FolderLock
from tofsi.runs.output import write_json
from tofsi.runs.output_size import RESERVE, file_size_limit
from tofsi.runs.provenance import now

log = logging.getLogger(__name__)

SYSTEM_FOLDERS = (Path("/dev"), Path("/proc"), Path("/sys"))
RUN_FILE = "run.json"
# Every name a tofsi command or example writes (a previous run's files without a run.json).
OUTPUT_PATTERNS = ("run.json", "diagnostic.json", "mesh.vtu", "mesh.png", "moved_mesh.*", "failed_mesh.*",
                   "move.json", "solve.json", "solution.vtu", "solution_*.png", "design_*.png",
                   "design_*.vtu", "design_series.pvd", "design.npy", "checkpoint.npz", "history.csv",
                   "history.json", "result.json", "convergence.png", "check_gradients.json",
                   "study.csv", "study.json", "study.png")
RESERVE_FILE = ".tofsi-reserve"
LONGEST_NAME = 64          # bytes: the longest file name a run writes, its temporary name included
STATUS = {0: "finished", 1: "checks failed", 2: "bad input", 3: "numerical failure",
          4: "write failure", 5: "unphysical result", 130: "interrupted", 143: "terminated"}


def _limit(folder: Path, name: str, default: int) -> int:
    try:
        return int(os.pathconf(folder, name))
    except (OSError, ValueError):
        return default


def _exists(path: Path) -> bool:
    """``path.exists()``, False for a name the system refuses to look up (too long)."""
    try:
        return path.exists()
    except OSError:
        return False


def check_names(real: Path, existing: Path, key: str, shown: str) -> None:
    """The folders still to create under ``existing`` have names the file system takes (no
    control characters, at most NAME_MAX bytes), and the longest path a run writes in
    ``real`` fits in PATH_MAX."""
    name_max = _limit(existing, "PC_NAME_MAX", 255)
    for part in real.relative_to(existing).parts:
        if any(unicodedata.category(c) == "Cc" for c in part):
            raise InputError(key, shown, f"has a control character (newline, tab, ...) in the folder "
                             f"name {part!r}; choose a plain name")
        if len(part.encode()) > name_max:
            raise InputError(key, shown, f"has a folder name of {len(part.encode())} bytes; the file "
                             f"system allows at most {name_max}")
    path_max = _limit(existing, "PC_PATH_MAX", 4096)
    longest = len(str(real).encode()) + 1 + LONGEST_NAME
    if longest > path_max:
        raise InputError(key, shown, f"is {len(str(real).encode())} bytes long; with the file names "
                         f"a run writes its paths exceed the file system's {path_max} bytes")


def check_writable(path, key: str = "--output", shown: str | None = None) -> Path:
    """Raise :class:`InputError` unless ``path`` is, or can become, a writable folder
    (``shown``: the value the message names, default ``path``)."""
    shown = str(path) if shown is None else shown
    real = Path(os.path.abspath(path)).resolve()
    for system in SYSTEM_FOLDERS:
        if real == system or system in real.parents:
            raise InputError(key, shown, f"lies in the system folder {system}; choose a folder for results")
    if _exists(real) and not real.is_dir():
        raise InputError(key, shown, "is a file, not a folder")
    existing = real
    while not _exists(existing):
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(key, shown, f"lies under {existing}, which is a file, not a folder")
    check_names(real, existing, key, shown)
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


def _remove(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass


class RunFolder:
    """The output folder of one run.

    program : how the run is named in ``run.json`` (``"tofsi optimize"``, an example's path)
    overwrite : replace a previous run's files (``--overwrite``)
    resume : continue the run in the folder (``--resume``; its files stay)
    replaces_own : a previous run of the same ``program`` is replaced without ``overwrite``
        (examples, whose folder is their own)
    key, shown : how messages name the folder (``"name"`` and the scene name for the
        default ``results/<name>``)
    """

    def __init__(self, path, program: str, overwrite: bool = False, resume: bool = False,
                 replaces_own: bool = False, key: str = "--output", shown: str | None = None):
        self.path, self.program = Path(path), program
        self.overwrite, self.resume, self.replaces_own = overwrite, resume, replaces_own
        self.key, self.shown = key, str(path) if shown is None else shown
        self.previous: dict | None = None
        self.foreign: set[str] = set()
        self.record: dict | None = None
        self.lock = FolderLock(self.path, program)
        self.created: list[Path] = []          # folders this run made (removed again if unused)

    @property
    def begun(self) -> bool:
        return self.record is not None

    def check(self) -> "RunFolder":
        """Before any computation: writable, not in use by another run (then locked until
        :meth:`finish`), and not holding another run's files (unless asked)."""
        real = check_writable(self.path, self.key, self.shown)
        missing = [p for p in [real, *real.parents] if not p.exists()]
        try:
            real.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise InputError(self.key, self.shown, f"cannot create the folder ({err.strerror or err})") from None
        self.created = missing
        try:
            self.lock.acquire(self.key)
            names = visible_files(self.path)
            self.previous = read_record(self.path)
            listed = set((self.previous or {}).get("files", []))
            self.foreign = {n for n in names if n not in listed
                            and not any(fnmatch.fnmatch(n, p) for p in OUTPUT_PATTERNS)}
            own = (self.replaces_own and self.previous is not None
                   and self.previous.get("program") == self.program)
            if names and not (self.overwrite or self.resume or own):
                raise InputError(self.key, self.shown,
                                 f"holds {describe(self.previous, names)}; add --overwrite to replace "
                                 "them, or choose a new --output folder")
        except BaseException:
            self.release()
            raise
        return self

    @property
    def replaced_bytes(self) -> float:
        """Bytes of the previous run's files that :meth:`begin` removes (0 when resuming)."""
        if self.resume:
            return 0.0
        names = [n for n in visible_files(self.path) if n not in self.foreign]
        return float(sum((self.path / n).stat().st_size for n in names if (self.path / n).is_file()))

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
        self._reserve()

    def _reserve(self) -> None:
        """Set aside room for the final run.json (released by :meth:`finish` before it writes):
        a full disk must not keep the record of the failure from being written."""
        size = int(min(RESERVE, 0.5 * file_size_limit()))
        try:
            with open(self.path / RESERVE_FILE, "wb") as fh:
                fh.write(b"\0" * size)
        except OSError as err:
            log.debug("%s: no reserve for run.json (%s)", self.path, err)
            _remove(self.path / RESERVE_FILE)

    def _clear(self) -> None:
        """Remove the previous run's files (run.json last: until then the folder is its)."""
        names = [n for n in visible_files(self.path) if n not in self.foreign]
        for name in sorted(names, key=lambda n: n == RUN_FILE):
            target = self.path / name
            if target.is_file() or target.is_symlink():
                target.unlink()
        if names:
            log.info("%s: removed %d file(s) of the previous run", self.path, len(names))

    def files(self) -> list[str]:
        """The run's files in the folder (every one complete: files are written atomically)."""
        return [n for n in visible_files(self.path) if n not in self.foreign]

    def finish(self, exit_status: int, **extra) -> WriteError | None:
        """Complete run.json (end time, exit status, status words, the files written) and
        unlock the folder. Returns the :class:`WriteError` if even a short run.json could not
        be written (a full record first, then one without the scene), else None."""
        try:
            if not self.begun:
                return None
            _remove(self.path / RESERVE_FILE)
            status = STATUS.get(exit_status, "failed")
            self.record.update(finished=now(), exit_status=exit_status, status=status, files=self.files(),
                               **{k: v for k, v in extra.items() if v is not None})
            try:
                write_json(self.path / RUN_FILE, self.record)
            except WriteError:
                short = {k: v for k, v in self.record.items() if k != "scene"}
                try:
                    write_json(self.path / RUN_FILE, short)
                except WriteError as err:
                    return err
            return None
        finally:
            self.release()

    def release(self) -> None:
        """Unlock the folder; a run that wrote nothing removes the folders it made."""
        self.lock.release()
        if self.begun:
            return
        for folder in self.created:                     # deepest first
            try:
                folder.rmdir()
            except OSError:
                break
        self.created = []
