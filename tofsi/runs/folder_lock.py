"""One run per output folder: a lock file that names its owner.

``.tofsi.lock`` in the output folder is created exclusively (``O_CREAT |
O_EXCL``) and holds the owner's pid, host, program and start time. The owner
also holds a POSIX record lock on it (``fcntl.lockf``) for as long as it
runs; the system drops that lock when the process ends, however it ends
(``SIGKILL`` included), and worker processes forked by the owner do not
inherit it. So:

* a second run into the folder finds the record lock held and is refused
  (:class:`~tofsi.core.errors.InputError` naming the first run);
* a lock file whose record lock nobody holds is *stale* (its run died
  without removing it): the new run takes the file over, logging whose it was;
* at the end of the run the file is removed (:meth:`FolderLock.release`,
  also at interpreter exit).

Record locks are per process, so one process cannot detect its own second
lock that way: locks held in this process are remembered as well.
"""

from __future__ import annotations

import atexit
import errno
import fcntl
import json
import logging
import os
import socket
import time
from pathlib import Path

from tofsi.core.errors import InputError
from tofsi.runs.provenance import now

log = logging.getLogger(__name__)

LOCK_NAME = ".tofsi.lock"
_HELD: set[str] = set()                       # lock paths held by this process


def _owner_text(owner: dict) -> str:
    """``tofsi optimize (pid 123 on host h, started ...)``, or what is known of it."""
    if not owner:
        return "another run (starting)"
    where = f"pid {owner.get('pid', '?')} on host {owner.get('host', '?')}"
    return f"{owner.get('program', 'another run')} ({where}, started {owner.get('started', '?')})"


def _read(fd: int) -> dict:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        owner = json.loads(os.read(fd, 65536).decode("utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return owner if isinstance(owner, dict) else {}


def _owner_once_written(fd: int, wait_s: float = 2.0) -> dict:
    """The owner's record, read again for up to ``wait_s`` while it is still empty: the owner
    writes it just after taking the record lock, so a run refused in between would otherwise
    name "another run (starting)" instead of the run that holds the folder."""
    deadline = time.monotonic() + wait_s
    owner = _read(fd)
    while not owner and time.monotonic() < deadline:
        time.sleep(0.02)
        owner = _read(fd)
    return owner


class FolderLock:
    """The lock of ``folder`` for a run of ``program`` (the folder must exist)."""

    def __init__(self, folder, program: str):
        self.path = Path(folder) / LOCK_NAME
        self.program = program
        self.fd: int | None = None
        self.real = ""                          # the lock's path, symbolic links resolved
        self.took_over: dict | None = None     # the stale owner's record, if taken over

    @property
    def held(self) -> bool:
        return self.fd is not None

    def acquire(self, key: str = "--output") -> "FolderLock":
        """Take the lock, or raise :class:`InputError` (``key``) naming the run that holds it."""
        real = os.path.realpath(self.path)
        if real in _HELD:
            raise InputError(key, str(self.path.parent), "is the output folder of a run going on in "
                             "this process; choose another folder")
        for _ in range(20):                    # retried only when the owner removes it meanwhile
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_RDWR, 0o644)
                created = True
            except FileExistsError:
                try:
                    fd = os.open(self.path, os.O_RDWR)
                except FileNotFoundError:
                    continue
                created = False
            try:
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as err:
                owner = _owner_once_written(fd)
                os.close(fd)
                if err.errno not in (errno.EACCES, errno.EAGAIN):
                    raise InputError(key, str(self.path.parent), f"cannot lock the folder "
                                     f"({err.strerror or err})") from None
                raise InputError(key, str(self.path.parent), f"is in use by {_owner_text(owner)}; "
                                 "wait for it to end or choose another output folder") from None
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if not same:                       # its owner removed it as we opened it: again
                os.close(fd)
                continue
            if not created:
                self.took_over = _read(fd)
                log.warning("%s: took over the lock of %s, which ended without removing it",
                            self.path.parent, _owner_text(self.took_over))
            self._write_owner(fd)
            self.fd, self.real = fd, real
            _HELD.add(real)
            atexit.register(self.release)
            return self
        raise InputError(key, str(self.path.parent), "could not take the folder's lock: other runs "
                         "keep creating and removing it")

    def _write_owner(self, fd: int) -> None:
        """Name the owner in the file (best effort: on a full disk the record lock still holds)."""
        owner = {"pid": os.getpid(), "host": socket.gethostname(), "program": self.program,
                 "started": now()}
        try:
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, (json.dumps(owner) + "\n").encode("utf-8"))
        except OSError as err:
            log.debug("%s: could not write the lock's owner (%s)", self.path, err)

    def release(self) -> None:
        """Remove the lock file and drop the lock (nothing if not held)."""
        if self.fd is None:
            return
        try:
            os.unlink(self.path)               # first: nobody may take a file still locked
        except OSError:
            pass
        os.close(self.fd)
        self.fd = None
        _HELD.discard(self.real)
        atexit.unregister(self.release)
