"""The ``tofsi`` command line: one subcommand per job.

Exit status: 0 success, 2 bad input (one line naming the key, the value and
what is allowed), 3 numerical failure (a diagnostic file is written to the
output folder), 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path

from tofsi.commands.context import RunContext
from tofsi.errors import InputError, NumericalError
from tofsi.output import default_output, to_json, write_json
from tofsi.scene import load_scene

COMMANDS = {
    "mesh": "build the scene's mesh; print sizes; write the mesh and a picture",
    "move": "mesh-motion study: move the mesh with the scene's mover; report quality",
    "optimize": "topology optimization with NLopt (MMA or CCSAQ)",
    "check-gradients": "adjoint versus finite differences, block by block and total",
    "solve": "forward analysis of the scene's design with the effects the scene enables",
    "study": "parametric sweep (stiffening factors, A20, kappa, increments, mesh size) to a CSV and a plot",
    "tune": "stiffening factors tuned by gradients (NLopt) for the best mesh quality of the scene's motion",
}


class _Parser(argparse.ArgumentParser):
    def error(self, message):                      # one line, status 2, no usage dump
        print(f"tofsi: error: {message} (see tofsi --help)", file=sys.stderr)
        sys.exit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tofsi", description="Topology optimization of fluid-structure "
                     "interaction on structured quadrilateral meshes.")
    parser.add_argument("--version", action="version", version="tofsi 0.1.0")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    for name, help_text in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.add_argument("scene", help="scene file (TOML), e.g. examples/scenes/foil_in_channel.toml")
        p.add_argument("--output", type=Path, default=None,
                       help="output folder (default results/<scene name>/)")
        p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="override a scene value by dotted key, e.g. --set mover.name=spring")
        p.add_argument("--json", action="store_true",
                       help="print one JSON object with the run's figures on stdout")
        p.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
        p.add_argument("-q", "--quiet", action="store_true", help="no progress or summary text")
        if name == "study":
            p.add_argument("--sweep", action="append", default=[], metavar="KEY=RANGE",
                           help="KEY=START:STOP:STEP, KEY=START:STOP:*FACTOR or KEY=V1,V2,... "
                                "(repeat for a grid; KEY[i] sweeps one list entry)")
            p.add_argument("--jobs", type=int, default=1, help="worker processes")
        if name == "optimize":
            p.add_argument("--resume", action="store_true",
                           help="continue exactly where an interrupted run in --output stopped")
        if name == "check-gradients":
            p.add_argument("--seed", type=int, default=0, help="seed of the random design and directions")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    ctx = None
    try:
        scene = load_scene(args.scene, args.set)
        ctx = RunContext(output=args.output or default_output(scene.name), json=args.json,
                         quiet=args.quiet)
        command = importlib.import_module(f"tofsi.commands.{args.command.replace('-', '_')}")
        figures = command.run(scene, args, ctx)
    except InputError as err:
        print(f"tofsi: error: {err}", file=sys.stderr)
        return 2
    except NumericalError as err:
        path = ctx.path("diagnostic.json") if ctx else Path("diagnostic.json")
        write_json(path, {"error": str(err), **err.diagnostic})
        print(f"tofsi: numerical failure: {err} (diagnostic: {path})", file=sys.stderr)
        if args.json:
            print(to_json({"error": str(err), "converged": False, "diagnostic": str(path)}))
        return 3
    except KeyboardInterrupt:
        hint = " (resume with --resume)" if args.command == "optimize" else ""
        print(f"tofsi: interrupted{hint}", file=sys.stderr)
        return 130
    if args.json:
        print(to_json(figures))
    return getattr(ctx, "exit_status", 0)


if __name__ == "__main__":
    sys.exit(main())
