"""What every subcommand shares: the output folder, printing, progress, provenance."""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from tofsi.core.errors import InputError


def stage_index(scene, text) -> int:
    """A continuation stage named on the command line: ``N`` (0 to the last) or ``last``."""
    text = str(text)
    n_stages = scene.design.n_stages
    stage = n_stages - 1 if text == "last" else (int(text) if text.isdigit() else -1)
    if not 0 <= stage < n_stages:
        raise InputError("--stage", text, f"allowed: 0 to {n_stages - 1} or last")
    return stage


@dataclass
class RunContext:
    """output : the output folder; folder : its :class:`~tofsi.runs.run_folder.RunFolder` (None:
    no checks, no run.json -- library use); record : the provenance run.json starts with."""

    output: Path
    json: bool = False
    quiet: bool = False
    written: list = field(default_factory=list)
    exit_status: int = 0
    folder: object = None
    record: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)      # more for run.json (e.g. stop_reason)

    @property
    def tty(self) -> bool:
        return sys.stderr.isatty()

    def say(self, text: str = "") -> None:
        """Human-readable output: stdout, or stderr when --json owns stdout."""
        if not self.quiet:
            print(text, file=sys.stderr if self.json else sys.stdout, flush=True)

    def warn(self, text: str) -> None:
        """A result the user must not take at face value: one line on stderr (even with -q),
        kept for run.json (``warnings``)."""
        print(f"warning: {text}", file=sys.stderr, flush=True)
        self.extra.setdefault("warnings", []).append(text)

    def begin(self) -> None:
        """Call before the first write: the previous run's files go, run.json is written."""
        if self.folder is not None:
            self.folder.begin(self.record)

    def finish(self, exit_status: int) -> None:
        """Complete run.json (if the run wrote anything)."""
        if self.folder is not None:
            self.folder.finish(exit_status, **self.extra)

    def path(self, name: str) -> Path:
        """A file in the output folder, remembered for the report."""
        p = self.output / name
        self.written.append(str(p))
        return p

    def progress(self, total: int, desc: str, every: float = 0.0):
        """Progress of a counted job: a bar on a terminal, else a line per step on stderr
        (at most one each ``every`` seconds, and always the last). Returns the callback
        ``update(done, total, info)`` movers and studies call; ``update.close()`` ends it."""
        bar = tqdm(total=total, desc=desc, file=sys.stderr, leave=False,
                   disable=self.quiet or not self.tty)
        last = [-float("inf")]

        def update(done, total_now, info):
            bar.total = max(bar.total or 0, total_now)
            bar.n = done
            if "min_skewness" in info:
                bar.set_postfix(min_skew=f"{info['min_skewness']:.3f}")
            bar.refresh()
            now = time.perf_counter()
            if not (self.quiet or self.tty) and (done >= total_now or now - last[0] >= every):
                last[0] = now
                note = f" ({info['note']})" if "note" in info else ""
                skew = f", min skewness {info['min_skewness']:.4f}" if "min_skewness" in info else ""
                print(f"{desc}: {done}/{total_now}{skew}{note}", file=sys.stderr, flush=True)
        update.close = bar.close
        return update

    @contextmanager
    def step(self, text: str):
        """A long step: its line on stderr as it starts, or a bar with the elapsed time on a
        terminal; nothing with --quiet."""
        if self.quiet:
            yield
            return
        if not self.tty:
            print(f"{text} ...", file=sys.stderr, flush=True)
            yield
            return
        bar = tqdm(total=None, desc=text, file=sys.stderr, leave=False, bar_format="{desc} [{elapsed}]")
        stop = threading.Event()

        def tick():
            while not stop.wait(0.5):
                bar.refresh()
        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
        try:
            yield
        finally:
            stop.set()
            ticker.join()
            bar.close()
