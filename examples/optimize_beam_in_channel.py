"""Design a structure that holds a wall up against channel flow -- the one-way example.

A wall (x in [0.975, 1.025], y in [0, 0.5]) stands in a 2 m x 1 m channel with
a parabolic inflow. We add material in the design region around it, clamped
to the channel floor, to make the wall and its support as stiff as possible
under the force the flow exerts on it (pressure, viscous shear and the
Brinkman friction of the porous solid), using at most a fifth of the design
region. The flow is steady Navier-Stokes with Brinkman friction in the
solid; the structure is linear elastic (SIMP); the coupling is one-way (the
deformation is 10 micrometres at E = 1e7 Pa). The adjoint gives the
gradient, NLopt's MMA takes the steps, and the projection gets sharper and
the Brinkman interpolation less convex stage by stage. About 75 seconds
on two cores; ``optimize_fsi.py`` is the two-way version with mesh motion:

    python examples/optimize_beam_in_channel.py [--output results/beam_in_channel_optimization]

A rerun replaces this example's earlier results; a folder holding another
run is refused unless ``--overwrite``. ``TOFSI_EXAMPLE_SMALL=1`` runs a
coarse mesh for a few iterations (seconds; the test suite does this).
"""

import argparse
import os
import sys
from pathlib import Path

import tofsi
from tofsi.commands.context import RunContext
from tofsi.commands.optimize import Pictures
from tofsi.core.errors import InputError, WriteError
from tofsi.optimization.optimize import Optimizer
from tofsi.runs.plotting import plot_convergence
from tofsi.runs.provenance import run_record
from tofsi.runs.run_folder import RunFolder

SCENE = Path(__file__).parent / "scenes" / "beam_in_channel_optimization.toml"
SMALL = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.15", "optimizer.max_iter=6",
         "design.stage_iterations=2", "optimizer.output_every=3"]


def main(output: Path, overrides=(), overwrite: bool = False) -> dict:
    if os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0":
        overrides = SMALL + list(overrides)
    scene = tofsi.load_scene(SCENE, list(overrides))
    folder = RunFolder(output, program="examples/optimize_beam_in_channel.py", overwrite=overwrite,
                       replaces_own=True).check()  # never beside another run's files
    problem = tofsi.Problem(scene)            # mesh, flow, structure, design map, objective
    print(f"{problem.n_design} design variables; the objective is the {scene.design.objective}")

    gamma = problem.initial_design()          # uniform, at the volume bound
    f, df = problem.evaluate(gamma)           # one flow + structure solve, one adjoint
    g, dg = problem.constraints(gamma)        # the volume needs no adjoint solve
    print(f"initial compliance {f:.4g} J/m, volume constraint {g[0]:+.3f} (<= 0 is feasible)")

    def report(it):                           # one line per design iteration
        if it.iteration % 10 == 0:
            print(f"  iteration {it.iteration:4d}  stage {it.stage}  compliance {it.objective:.5g}"
                  f"  volume {it.volume:.4f}  {it.time_s:6.1f} s")

    ctx = RunContext(output=Path(output), folder=folder,   # run.json: scene, versions, times
                     record=run_record(scene, overrides, sys.argv, folder.program))
    ctx.begin()
    optimizer = Optimizer(problem, output, on_iteration=report, on_picture=Pictures(ctx, problem))
    result = optimizer.run()
    plot_convergence(Path(output) / "convergence.png", [h.__dict__ for h in optimizer.history],
                     title="beam in a channel", objective_label=problem.objective.axis_label())
    ctx.extra["stop_reason"] = result["stop_reason"]
    ctx.finish(0)
    print(f"final compliance {result['objective']:.5g} J/m (from {f:.4g}), volume {result['volume']:.4f},"
          f" non-discreteness {result['non_discreteness_percent']:.1f} %, drag {result['drag']:.3g} N/m")
    print(f"pictures, VTU series (design_series.pvd), history and checkpoint in {output}")
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("results/beam_in_channel_optimization"))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--overwrite", action="store_true", help="replace another run's files in --output")
    args = parser.parse_args()
    try:
        main(args.output, args.set, args.overwrite)
    except (InputError, WriteError) as err:          # bad input (2), a file not written (4)
        print(f"error: {err}", file=sys.stderr)
        sys.exit(err.exit_status)
