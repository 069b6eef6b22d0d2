"""Design a structure that holds a wall up against channel flow -- the main example.

A wall (x in [0.975, 1.025], y in [0, 0.5]) stands in a 2 m x 1 m channel with
a parabolic inflow. We add material in the design region around it, clamped
to the channel floor, to make the wall and its support as stiff as possible
under the flow's pressure and viscous load (minimum compliance), using at
most a fifth of the design region. The flow is steady Navier-Stokes with
Brinkman friction in the solid; the structure is linear elastic (SIMP); the
coupling is one-way (the deformation is small at E = 1e5 Pa). The adjoint
gives the gradient, NLopt's MMA takes the steps, and the projection gets
sharper stage by stage. Takes a few minutes on two cores:

    python examples/optimize_beam_in_channel.py [--output results/beam_in_channel_optimization]
"""

import argparse
from pathlib import Path

import tofsi
from tofsi.commands.optimize import Pictures
from tofsi.commands.context import RunContext
from tofsi.optimize import Optimizer
from tofsi.plotting import plot_convergence

SCENE = Path(__file__).parent / "scenes" / "beam_in_channel_optimization.toml"


def main(output: Path, overrides=()) -> dict:
    scene = tofsi.load_scene(SCENE, list(overrides))
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

    ctx = RunContext(output=Path(output))
    optimizer = Optimizer(problem, output, on_iteration=report, on_picture=Pictures(ctx, problem))
    result = optimizer.run()
    plot_convergence(Path(output) / "convergence.png", [h.__dict__ for h in optimizer.history],
                     title="beam in a channel: compliance")
    print(f"final compliance {result['objective']:.5g} J/m (from {f:.4g}), volume {result['volume']:.4f},"
          f" non-discreteness {result['non_discreteness_percent']:.1f} %, drag {result['drag']:.3g} N/m")
    print(f"pictures, VTU series (design_series.pvd), history and checkpoint in {output}")
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("results/beam_in_channel_optimization"))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    main(args.output, args.set)
