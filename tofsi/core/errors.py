"""Exceptions with the exit status the command line maps them to.

``InputError`` (status 2) means the user asked for something that is not
allowed; its message names the key, the value and what is allowed.
``NumericalError`` (status 3) means a solver could not deliver a trustworthy
result; it carries a diagnostic dictionary (iteration history, worst element)
that the command line writes next to the results. ``WriteError`` (status 4)
means a result file could not be written (disk full, a file-size limit, a
name too long): it names the file and the reason.
"""

from __future__ import annotations

from typing import Any


class TofsiError(Exception):
    """Base class of every error the toolkit raises on purpose."""

    exit_status = 1


class InputError(TofsiError, ValueError):
    """Bad input: an unknown key, a value out of range, an unreadable file."""

    exit_status = 2

    def __init__(self, key: str, value: Any, allowed: str):
        self.key, self.value, self.allowed = key, value, allowed
        super().__init__(self._text())

    def _text(self) -> str:
        shown = repr(self.value)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        return f"{self.key} = {shown}: {self.allowed}"

    def __reduce__(self):                      # picklable (errors of study worker processes)
        return (InputError, (self.key, self.value, self.allowed))

    def under(self, prefix: str) -> "InputError":
        """The same error with its key qualified by a parent table name."""
        key = f"{prefix}.{self.key}" if prefix and self.key else (prefix or self.key)
        return InputError(key, self.value, self.allowed)


class NumericalError(TofsiError, RuntimeError):
    """A solver failed: no convergence, an inverted element, a singular system."""

    exit_status = 3

    def __init__(self, message: str, diagnostic: dict | None = None, state=None):
        self.diagnostic = dict(diagnostic or {})
        self.state = state        # the last state reached (e.g. a mesh displacement), if any
        self.solved = {}          # the fields a coupled sweep solved before this failure, by name
        self.accepted = None      # a failed load ramp's last converged state (None: none)
        super().__init__(message)

    def __reduce__(self):
        """Picklable (errors of study worker processes): the message and the diagnostic. The
        state and the solved fields stay behind: they are large, and only the process that
        failed continues from them (the inflow ramp), never a receiver of the error."""
        return (NumericalError, (str(self), self.diagnostic))


class WriteError(TofsiError):
    """A result file could not be written: ``path`` (the file meant), ``reason`` (the
    system's words, e.g. "No space left on device") and ``errno``."""

    exit_status = 4

    def __init__(self, path, reason: str, errno: int | None = None):
        self.path, self.reason, self.errno = str(path), reason, errno
        super().__init__(f"could not write {self.path} ({reason})")

    def __reduce__(self):
        return (WriteError, (self.path, self.reason, self.errno))

    @classmethod
    def of(cls, path, err: OSError) -> "WriteError":
        """The :class:`WriteError` of writing ``path`` that failed with ``err``."""
        return cls(path, err.strerror or str(err), err.errno)
