"""Does mesh motion change the design? Two-way versus one-way coupled optimization.

The structure of ``beam_in_channel_optimization_fsi`` is soft (E = 2 kPa): the
flow moves it by several centimetres, and with two-way coupling the flow is
solved on the mesh the Yeoh mover moves along. We

1. optimize one-way (flow on the undeformed mesh) through the whole
   continuation schedule -- the common starting point;
2. continue from it with two-way coupling (the scene as it is);
3. continue from it one-way for the same number of iterations (the control);

then evaluate both final designs with two-way coupling and compare their
compliance and how many design elements differ. About 15 minutes on two cores:

    python examples/compare_mesh_motion.py [--output results/compare_mesh_motion]

``TOFSI_EXAMPLE_SMALL=1`` runs the same steps on a coarse mesh for a few
iterations (the test suite does this).
"""

import argparse
import json
import os
from pathlib import Path

import numpy as np

import tofsi
from tofsi.optimize import Optimizer, non_discreteness
from tofsi.plotting import plot_design

SCENE = Path(__file__).parent / "scenes" / "beam_in_channel_optimization_fsi.toml"
SMALL = os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0"
BASE = (["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.2", "structure.youngs_modulus=1e5"]
        if SMALL else [])                            # small: stiff enough for a gray design
ITERATIONS = (4, 2) if SMALL else (120, 40)      # one-way start, each continuation


def optimize(name, output, overrides):
    scene = tofsi.load_scene(SCENE, BASE + overrides)
    problem = tofsi.Problem(scene)

    def line(it):
        if it.iteration % 10 == 0:
            print(f"  {name}: iteration {it.iteration:3d}  compliance {it.objective:.5g}  "
                  f"volume {it.volume:.4f}")
    optimizer = Optimizer(problem, output / name, on_iteration=line)
    result = optimizer.run()
    return np.load(output / name / "design.npy"), result


def main(output: Path) -> dict:
    one_way = ["effects.coupling=one-way", "design.beta=[1.0, 2.0, 4.0, 8.0, 16.0]",
               f"optimizer.max_iter={ITERATIONS[0]}"] + (["design.stage_iterations=1"] if SMALL else [])
    print("1. one-way optimization (the common start)")
    start, _ = optimize("one_way", output, one_way)
    np.save(output / "start.npy", start)
    follow = [f"design.initial={output / 'start.npy'}", f"optimizer.max_iter={ITERATIONS[1]}"]
    print("2. continued with two-way coupling (mesh motion on)")
    two, r_two = optimize("two_way", output, follow)
    print("3. continued one-way (mesh motion off: the control)")
    ctrl, r_ctrl = optimize("control", output, follow + ["effects.coupling=one-way"])

    judge = tofsi.Problem(tofsi.load_scene(SCENE, BASE))    # two-way physics decides
    rows = {}
    for name, gamma in (("two_way", two), ("control", ctrl)):
        state = judge.solve(gamma)
        rows[name] = {"compliance_two_way": judge.model.figures(state)["compliance"],
                      "max_displacement_m": float(np.abs(state.u).max()),
                      "non_discreteness_percent": non_discreteness(judge.densities(gamma)[judge.map.design])}
        plot_design(output / f"{name}.png", judge.model.mesh.points + state.mesh_displacement,
                    judge.model.mesh.quads, state.rho, title=f"{name.replace('_', '-')} design "
                    f"(two-way compliance {rows[name]['compliance_two_way']:.4g})")
    rho_two, rho_ctrl = judge.densities(two)[judge.map.design], judge.densities(ctrl)[judge.map.design]
    summary = {"designs": rows,
               "compliance_change_percent": 100 * (rows["two_way"]["compliance_two_way"]
                                                   / rows["control"]["compliance_two_way"] - 1),
               "elements_that_differ_percent": float(100 * np.mean(np.abs(rho_two - rho_ctrl) > 0.5)),
               "optimizer_objectives": {"two_way": r_two["objective"], "control": r_ctrl["objective"]}}
    (output / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("results/compare_mesh_motion"))
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    main(args.output)
