"""The ``tofsi`` command line: one subcommand per job.

Exit status: 0 success, 1 a failed gradient check, 2 bad input (one line
naming the key, the value and what is allowed; nothing is written), 3
numerical failure (a diagnostic file is written to the output folder), 4 a
result file could not be written (disk full, a file-size limit: one line
naming the file, the reason and the complete files kept; ``run.json`` says
``"status": "write failure"``), 5 a result that is no physical state
(``solve``: a small-strain displacement beyond the channel; written, with
``physical: false``), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM,
handled like Ctrl-C).

Before any computation the output folder is checked: it must be writable,
with room for the run's files (:mod:`tofsi.runs.output_size`), not in use by
another run (a lock, :mod:`tofsi.runs.folder_lock`), and a fresh run refuses a
folder holding another run's files unless ``--overwrite`` (``--resume``
continues the run in it). Every folder a run writes gets a ``run.json``
with the run's provenance (:mod:`tofsi.runs.provenance`).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import json
import logging
import math
import os
import signal
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import tofsi
from tofsi.commands.context import RunContext
from tofsi.commands.hints import hint
from tofsi.core.errors import InputError, NumericalError, WriteError
from tofsi.runs.memory import check as check_memory
from tofsi.runs.output import default_output, to_json, write_json
from tofsi.runs.output_size import check_room
from tofsi.runs.provenance import run_record
from tofsi.runs.run_folder import RunFolder
from tofsi.scene.scene import load_scene
from tofsi.linalg.threads import configure as configure_linear_algebra, mpi_rank

COMMANDS = {
    "mesh": "build the scene's mesh; print sizes; write the mesh and a picture",
    "move": "mesh-motion study: move the mesh with the scene's mover; report quality",
    "optimize": "topology optimization with NLopt (MMA or CCSAQ)",
    "check-gradients": "adjoint versus finite differences, block by block and total",
    "solve": "forward analysis of the scene's design (or a saved one) with the effects the scene enables",
    "study": "parametric sweep (stiffening factors, A20, kappa, increments, mesh size) to a CSV and a plot",
    "tune": "stiffening factors tuned by gradients (NLopt) for the best mesh quality of the scene's motion",
}
QUALITY = ("min_skewness", "n_inverted", "min_area_change", "max_area_change")
WRITE_ERRNOS = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.ENAMETOOLONG, errno.EROFS)
LARGE_SCENE = 1e6             # bytes: a scene file this large is announced before it is read
LOGGERS = ("tofsi", "movers", "adjoint")          # -v raises only these; third parties stay quiet


class UsageError(Exception):
    """A malformed command line (argparse's complaint)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the run stops where it is, its checkpoint stays."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):                      # one line, status 2, no usage dump
        raise UsageError(f"{message} (see tofsi --help)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tofsi", description="Topology optimization of fluid-structure "
                     "interaction on structured quadrilateral meshes.")
    parser.add_argument("--version", action="version", version=f"tofsi {tofsi.__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    for name, help_text in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.add_argument("scene", help="scene file (TOML), e.g. examples/scenes/foil_in_channel.toml")
        p.add_argument("--output", type=Path, default=None,
                       help="output folder (default results/<scene name>/)")
        p.add_argument("--overwrite", action="store_true",
                       help="replace the files of a previous run in the output folder")
        p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="override a scene value by dotted key, e.g. --set mover.name=spring; "
                            "KEY[i]=VALUE replaces entry i of a list, e.g. --set mover.layers[0]=2")
        p.add_argument("--json", action="store_true",
                       help="print one JSON object with the run's figures on stdout")
        p.add_argument("-v", "--verbose", action="count", default=0,
                       help="more log output (-v: solver iterations and residuals, -vv: debug)")
        p.add_argument("-q", "--quiet", action="store_true", help="no progress or summary text")
        p.add_argument("--max-memory", type=float, default=None, metavar="GB",
                       help="refuse a run estimated to need more memory (default: solver.max_memory_gb, "
                            "else the memory available now)")
        if name == "study":
            p.add_argument("--sweep", action="append", default=[], metavar="KEY=RANGE",
                           help="KEY=START:STOP:STEP, KEY=START:STOP:*FACTOR or KEY=V1,V2,... "
                                "(repeat for a grid; KEY[i] sweeps one list entry)")
            p.add_argument("--jobs", type=int, default=1, help="worker processes (1 or more)")
        if name == "optimize":
            p.add_argument("--resume", action="store_true",
                           help="continue exactly where an interrupted run in --output stopped")
        if name == "solve":
            p.add_argument("--allow-unphysical", action="store_true",
                           help="accept a one-way small-strain state whose displacement exceeds the "
                                "channel (exit 0 with a warning; without it: exit 5)")
            p.add_argument("--stage", default="0", metavar="N|last",
                           help="continuation stage whose projection, SIMP penalty and Brinkman q "
                                "apply (default 0: optimize's first iteration from this design; "
                                "result.json's stage: that run's final figures; last: the "
                                "schedule's last stage)")
        if name == "check-gradients":
            p.add_argument("--seed", type=int, default=0, help="seed of the random design and directions")
            p.add_argument("--stage", default=None, metavar="N|last",
                           help="continuation stage to check (default: the scene's first two-way stage, "
                                "else 0)")
        if name in ("solve", "check-gradients"):
            p.add_argument("--design", type=Path, default=None, metavar="FILE",
                           help="a saved design (design.npy of tofsi optimize); the same as "
                                "--set design.initial=FILE")
    return parser


def configure_logging(verbose: int) -> None:
    """Warnings by default; ``-v`` shows tofsi's solver iterations, ``-vv`` its debug lines.
    Other libraries (matplotlib, PIL, ...) stay at warnings whatever ``-v`` says."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    level = (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    for name in LOGGERS:
        logging.getLogger(name).setLevel(level)


@contextmanager
def sigterm_as_interrupt():
    """Within the block SIGTERM raises :class:`Terminated` (a KeyboardInterrupt)."""
    def handler(signum, frame):
        raise Terminated()
    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:                             # not the main thread: leave signals alone
        previous = None
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def scene_overrides(args) -> list[str]:
    """``--set`` values, plus ``--design FILE`` as ``design.initial``."""
    overrides = list(args.set)
    if getattr(args, "design", None) is not None:
        overrides.append(f"design.initial={json.dumps(str(args.design))}")
    return overrides


def check_options(args) -> None:
    """Command-line values that no scene key checks."""
    gb = args.max_memory
    if gb is not None and not (math.isfinite(gb) and gb > 0):
        raise InputError("--max-memory", gb, "allowed: a memory limit in GB > 0")
    if getattr(args, "resume", False) and args.overwrite:
        raise InputError("--resume", True, "cannot go with --overwrite (--resume continues the run "
                         "in --output, --overwrite replaces it); give one of them")


def announce_large_scene(path, quiet: bool) -> None:
    """A line on stderr before reading a scene file of megabytes (it takes seconds)."""
    try:
        size = os.stat(path).st_size
    except OSError:
        return
    if size > LARGE_SCENE and not quiet:
        print(f"reading the scene file {path} ({size / 1e6:.0f} MB) ...", file=sys.stderr, flush=True)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
    except UsageError as err:
        return _error(f"tofsi: error: {err}", {"error": str(err)}, "--json" in argv, 2)
    configure_logging(args.verbose)
    with sigterm_as_interrupt():
        return _run(args, argv)


def _error(line: str, payload: dict, as_json: bool, status: int) -> int:
    print(line, file=sys.stderr)
    if as_json:
        print(to_json({**payload, "exit_status": status}))
    return status


def _run(args, argv) -> int:
    ctx, scene, folder = None, None, None
    try:
        try:
            check_options(args)
            overrides = scene_overrides(args)
            announce_large_scene(args.scene, args.quiet)
            scene = load_scene(args.scene, overrides)
            check_memory(scene, args.command, args.max_memory, getattr(args, "jobs", 1))   # before building
            if args.command != "mesh":
                configure_linear_algebra(scene.solver)
            if mpi_rank() > 0:                     # mpiexec: rank 0 writes and prints
                args.output, args.json, args.quiet = Path(tempfile.mkdtemp()), False, True
            where = {"key": "--output", "shown": str(args.output)} if args.output else {"key": "name",
                                                                                         "shown": scene.name}
            folder = RunFolder(args.output or default_output(scene.name), program=f"tofsi {args.command}",
                               overwrite=args.overwrite, resume=getattr(args, "resume", False), **where).check()
            check_room(folder.path, scene, args.command, folder.replaced_bytes)
            ctx = RunContext(output=folder.path, json=args.json, quiet=args.quiet, folder=folder,
                             record=run_record(scene, overrides, ["tofsi", *argv], f"tofsi {args.command}"))
            command = importlib.import_module(f"tofsi.commands.{args.command.replace('-', '_')}")
            figures = command.run(scene, args, ctx)
        except OSError as err:                     # a write that did not go through atomic_write
            if err.errno not in WRITE_ERRNOS:
                raise
            raise WriteError.of(err.filename or "a file", err) from err
        unrecorded = _finish(ctx, ctx.exit_status)
        if unrecorded is not None:                 # the results are complete, their record is not
            raise unrecorded
    except InputError as err:
        _finish(ctx, 2)
        return _error(f"tofsi: error: {err}", {"error": str(err), "key": err.key}, args.json, 2)
    except NumericalError as err:
        return _numerical_failure(err, args, ctx, scene)
    except WriteError as err:
        return _write_failure(err, args, ctx)
    except KeyboardInterrupt as err:
        status = 143 if isinstance(err, Terminated) else 130
        if ctx is not None:
            ctx.extra["stop_reason"] = "interrupted" if args.command == "optimize" else None
        _finish(ctx, status)
        how = "terminated" if status == 143 else "interrupted"
        resume = " (resume with --resume)" if args.command == "optimize" and ctx and ctx.folder.begun else ""
        return _error(f"tofsi: {how}{resume}", {"error": how}, args.json, status)
    finally:
        if folder is not None:
            folder.release()
    if args.json:
        print(to_json(figures))
    return ctx.exit_status


def _finish(ctx, status: int, **more) -> WriteError | None:
    """Complete run.json (when the run wrote anything) and unlock the folder."""
    if ctx is None or ctx.folder is None:
        return None
    return ctx.folder.finish(status, **ctx.extra, **more)


def _numerical_failure(err: NumericalError, args, ctx, scene) -> int:
    """Exit 3: the diagnostic goes beside the results (when it can be written)."""
    path, unwritten = None, ""
    if ctx is not None:
        try:
            ctx.begin()
            path = ctx.path("diagnostic.json")
            write_json(path, {"error": str(err), **err.diagnostic})
        except WriteError as failure:
            path, unwritten = None, f"; {failure}"
        ctx.extra.setdefault("stop_reason", "numerical failure" if args.command == "optimize" else None)
        _finish(ctx, 3)
    extra = hint(err, scene, args.command)
    quality = err.diagnostic.get("quality", {})
    payload = {"error": str(err), "converged": False, "diagnostic": str(path),
               **{k: quality[k] for k in QUALITY if k in quality}}
    return _error(f"tofsi: numerical failure: {err}{'; ' + extra if extra else ''} (diagnostic: {path})"
                  f"{unwritten}", payload, args.json, 3)


def _write_failure(err: WriteError, args, ctx) -> int:
    """Exit 4, one line: the file that could not be written and why, the complete files kept,
    and whether run.json records it."""
    kept, record = [], ""
    if ctx is not None and ctx.folder is not None and ctx.folder.begun:
        failure = {"file": err.path, "error": err.reason}
        unrecorded = _finish(ctx, 4, write_failure=failure)
        kept = ctx.folder.files()
        record = ("; run.json records the failure" if unrecorded is None else
                  f"; run.json could not be updated either ({unrecorded.reason})")
    else:
        _finish(ctx, 4)
    where = f" in {ctx.output}" if ctx is not None else ""
    shown = ", ".join(kept[:8]) + (f" and {len(kept) - 8} more" if len(kept) > 8 else "")
    kept_text = f"kept {len(kept)} complete file(s){where}: {shown}" if kept else f"nothing was kept{where}"
    payload = {"error": str(err), "file": err.path, "reason": err.reason, "kept": kept}
    return _error(f"tofsi: write failure: {err}; {kept_text}{record}", payload, args.json, 4)


if __name__ == "__main__":
    sys.exit(main())
