"""What every subcommand shares: the output folder, printing, progress."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm


@dataclass
class RunContext:
    output: Path
    json: bool = False
    quiet: bool = False
    written: list = field(default_factory=list)
    exit_status: int = 0

    def say(self, text: str = "") -> None:
        """Human-readable output: stdout, or stderr when --json owns stdout."""
        if not self.quiet:
            print(text, file=sys.stderr if self.json else sys.stdout)

    def path(self, name: str) -> Path:
        """A file in the output folder, remembered for the report."""
        p = self.output / name
        self.written.append(str(p))
        return p

    def progress(self, total: int, desc: str):
        """A progress bar on stderr; returns the callback movers and solvers call."""
        bar = tqdm(total=total, desc=desc, file=sys.stderr, leave=False,
                   disable=self.quiet or not sys.stderr.isatty())

        def update(done, total_now, info):
            bar.total = max(bar.total or 0, total_now)
            bar.n = done
            if "min_skewness" in info:
                bar.set_postfix(min_skew=f"{info['min_skewness']:.3f}")
            bar.refresh()
        update.close = bar.close
        return update
