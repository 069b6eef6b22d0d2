"""Design a soft structure against the flow that it deforms -- two-way coupled topology optimization.

The wall-in-a-channel problem of ``optimize_beam_in_channel.py``, but the
structure is soft (E = 5 kPa): the flow moves it by centimetres, the fluid
mesh follows it (a mesh mover: Yeoh hyperelastic by default, with the two
element layers around the evolving design stiffened), and the flow is solved
on the moved mesh. The gradient comes from the block adjoint of the coupled
flow-structure-mesh system. The continuation starts one-way (it finds the
topology at one-way cost from the uniform design) and ends two-way (it
designs against the deforming flow); every two-way iteration records the
quality of the moved mesh. About a minute and a half on two cores:

    python examples/optimize_fsi.py [--output results/beam_in_channel_optimization_fsi]
    python examples/optimize_fsi.py --set mover.name=spring     # or linear, yeoh

``TOFSI_EXAMPLE_SMALL=1`` runs a coarse mesh for a few iterations (the test suite does this).
"""

import argparse
import math
import os
import sys
from pathlib import Path

import tofsi
from tofsi.commands.context import RunContext
from tofsi.commands.hints import describe
from tofsi.commands.optimize import Pictures
from tofsi.coupling.coupled import continuation
from tofsi.core.errors import InputError, WriteError
from tofsi.optimization.optimize import Optimizer
from tofsi.runs.plotting import plot_convergence
from tofsi.runs.provenance import run_record
from tofsi.runs.run_folder import RunFolder

SCENE = Path(__file__).parent / "scenes" / "beam_in_channel_optimization_fsi.toml"
SMALL = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.2", "optimizer.max_iter=6",
         "design.beta=[1.0, 2.0]", 'design.coupling=["one-way", "two-way"]', "design.stage_iterations=3",
         "optimizer.output_every=3", "structure.youngs_modulus=1e6"]     # stiff: a gray coarse design


def main(output: Path, overrides=(), overwrite: bool = False) -> dict:
    """The two-way example at small motion: the scene above, with ``SMALL`` in small mode."""
    return optimize_scene(SCENE, output, overrides, overwrite, SMALL,
                          "Young's modulus raised from 5 kPa to 1 MPa, so the coarse gray designs of six "
                          "iterations hold against the flow", "examples/optimize_fsi.py")


def optimize_scene(scene_file: Path, output: Path, overrides=(), overwrite: bool = False, small=(),
                   small_note: str = "", program: str = "") -> dict:
    """Optimize a two-way scene into ``output`` with a line per ten iterations (every two-way one),
    pictures, the VTU series, the convergence plot and the run's provenance; in small mode
    (``TOFSI_EXAMPLE_SMALL``) with the overrides ``small`` first, saying what they change."""
    if os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0":
        overrides = list(small) + list(overrides)
        print("small mode (TOFSI_EXAMPLE_SMALL): " + ", ".join(small) + (f" -- {small_note}" if small_note else ""))
    scene = tofsi.load_scene(scene_file, list(overrides))
    folder = RunFolder(output, program=program, overwrite=overwrite, replaces_own=True).check()
    problem = tofsi.Problem(scene)         # flow, structure and mesh motion: a two-way block system
    d = scene.design
    stages = [f"beta {continuation(scene, k).params.beta:g} {continuation(scene, k).coupling or scene.effects.coupling}"
              for k in range(d.n_stages)]
    print(f"{problem.n_design} design variables, mover {scene.mover.name}, "
          f"{problem.model.mesh.n_elements} elements; stages: " + ", ".join(stages))

    def report(it):                        # one line per ten design iterations
        if it.iteration % 10 == 0 or it.coupling == "two-way":
            quality = "" if math.isnan(it.min_skewness) else (f"  min skewness {it.min_skewness:.3f}"
                                                               f"  interface gap {it.max_interface_gap:.2g} m")
            print(f"  iteration {it.iteration:4d}  {it.coupling:7s}  compliance {it.objective:.5g}"
                  f"  volume {it.volume:.4f}{quality}  {it.time_s:6.1f} s")

    def fallback(iteration, fallbacks, step, error):
        print(f"  iteration {iteration:4d}  a trial design failed ({describe(error, 120)}); back to the last good "
              f"design, move limit {step:.3g} (fallback {fallbacks})")

    ctx = RunContext(output=Path(output), folder=folder,
                     record=run_record(scene, overrides, sys.argv, folder.program))
    ctx.begin()
    optimizer = Optimizer(problem, output, on_iteration=report, on_picture=Pictures(ctx, problem),
                          on_fallback=fallback)
    result = optimizer.run()
    history = [h.__dict__ for h in optimizer.history]
    plot_convergence(Path(output) / "convergence.png", history, title=f"two-way, {scene.mover.name} mover",
                     objective_label=problem.objective.axis_label())
    skew = [h["min_skewness"] for h in history if not math.isnan(h["min_skewness"])]
    result["min_skewness_over_run"] = min(skew) if skew else float("nan")
    ctx.extra["stop_reason"] = result["stop_reason"]
    ctx.finish(0)
    print(f"final compliance {result['objective']:.5g} J/m, volume {result['volume']:.4f}, largest "
          f"displacement {result['max_displacement']:.3g} m, min skewness over the two-way stages "
          f"{result['min_skewness_over_run']:.3f}, {result['fallbacks']} fallbacks, {result['wall_time_s']:.0f} s")
    print(f"pictures, VTU series (design_series.pvd), history and checkpoint in {output}")
    return result


def command_line(doc: str, run, default: Path) -> None:
    """An example's command line: ``--output`` (default ``default``), ``--set KEY=VALUE``,
    ``--overwrite``; ``run(output, overrides, overwrite)``; bad input exits 2, a file not
    written 4, with one line on stderr."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--output", type=Path, default=default)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--overwrite", action="store_true", help="replace another run's files in --output")
    args = parser.parse_args()
    try:
        run(args.output, args.set, args.overwrite)
    except (InputError, WriteError) as err:          # bad input (2), a file not written (4)
        print(f"error: {err}", file=sys.stderr)
        sys.exit(err.exit_status)


if __name__ == "__main__":
    command_line(__doc__, main, default=Path("results/beam_in_channel_optimization_fsi"))
