"""Does mesh motion change the design, and does density-dependent stiffening keep the mesh valid?

The two-way scene ``beam_in_channel_optimization_fsi`` (soft structure,
E = 5 kPa, Yeoh mover) is optimized from the uniform design through its
one-way stages once (they find the topology; the mover plays no part in
them), and its last stage (beta 16) is then run from that design four ways:

1. as shipped: two-way, with the two element layers around the *evolving
   design* stiffened (``mover.layers_from = "density"``);
2. two-way with the same layers counted from the fixed solid only
   (``mover.layers_from = "solid"``);
3. two-way without stiffening (``mover.layers = []``);
4. one-way (the control: the flow never sees the deformation);

then every final design is judged with two-way coupling (compliance, how many
design elements differ from the control), and runs 1-3 are compared by the
smallest element skewness of the moved mesh along their two-way stage. About
eight minutes on two cores:

    python examples/compare_mesh_motion.py [--output results/compare_mesh_motion]

``TOFSI_EXAMPLE_SMALL=1`` runs the same steps on a coarse mesh for a few
iterations (the test suite does this).
"""

import argparse
import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np

import tofsi
from tofsi.optimization.optimize import Optimizer, non_discreteness
from tofsi.runs.plotting import plot_design, region_outlines

SCENE = Path(__file__).parent / "scenes" / "beam_in_channel_optimization_fsi.toml"
SMALL = os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0"
BASE = (["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.2", "structure.youngs_modulus=1e6",
         "optimizer.max_iter=6", "design.beta=[1.0, 2.0]", 'design.coupling=["one-way", "two-way"]',
         "design.stage_iterations=3"] if SMALL else [])
RUNS = {"density_layers": [], "solid_layers": ["mover.layers_from=solid"], "no_stiffening": ["mover.layers=[]"],
        "one_way_control": ['design.coupling=["one-way"]']}


def split_schedule(scene) -> tuple[list[str], list[str]]:
    """Overrides for the schedule's one-way stages alone, and for its last stage from their design."""
    d, iterations = scene.design, scene.optimizer.max_iter
    first, coupling = len(d.beta) - 1, list(d.coupling)
    if first < 1 or coupling[:first] != ["one-way"] * first or coupling[-1:] != ["two-way"]:
        raise SystemExit(f"{SCENE.name}: expected one-way stages, then one two-way stage")
    one_way = [f"design.beta={json.dumps(list(d.beta[:first]))}", f"design.coupling={json.dumps(coupling[:first])}",
               f"optimizer.max_iter={first * d.stage_iterations}"]
    last = [f"design.beta=[{d.beta[-1]}]", 'design.coupling=["two-way"]',
            f"optimizer.max_iter={iterations - first * d.stage_iterations}"]
    return one_way, last


def optimize(name, output, overrides):
    problem = tofsi.Problem(tofsi.load_scene(SCENE, BASE + overrides))

    def line(it):
        if it.iteration % 10 == 0:
            print(f"  {name}: iteration {it.iteration:3d}  {it.coupling:7s}  compliance {it.objective:.5g}")
    optimizer = Optimizer(problem, output / name, on_iteration=line)
    result = optimizer.run()
    skew = [h.min_skewness for h in optimizer.history if not math.isnan(h.min_skewness)]
    return np.load(output / name / "design.npy"), result, skew


def main(output: Path) -> dict:
    one_way, last = split_schedule(tofsi.load_scene(SCENE, BASE))
    print("one-way stages (shared)")
    _, shared, _ = optimize("one_way_stages", output, one_way)
    start = [f"design.initial={(output / 'one_way_stages' / 'design.npy').resolve()}"]
    designs, runs = {}, {}
    for name, overrides in RUNS.items():
        print(f"{name}: {' '.join(overrides) or 'as shipped'}")
        designs[name], result, skew = optimize(name, output, start + last + overrides)
        runs[name] = {"optimizer_objective": result["objective"],
                      "wall_time_s": shared["wall_time_s"] + result["wall_time_s"],
                      "min_skewness_over_run": min(skew) if skew else None,
                      "min_skewness_history": skew}
    judge = tofsi.Problem(tofsi.load_scene(SCENE, BASE))         # two-way physics decides
    judge.set_stage(dataclasses.replace(judge.params, beta=judge.scene.design.beta[-1], coupling="two-way"))
    control = judge.densities(designs["one_way_control"])[judge.map.design]
    for name, gamma in designs.items():
        state = judge.solve(gamma)
        figures = judge.model.figures(state)
        rho = judge.densities(gamma)[judge.map.design]
        runs[name].update(compliance_two_way=figures["compliance"], max_displacement_m=figures["max_displacement"],
                          non_discreteness_percent=non_discreteness(rho),
                          elements_differing_from_control_percent=float(100 * np.mean(np.abs(rho - control) > 0.5)))
        mesh = judge.model.mesh
        plot_design(output / f"{name}.png", mesh.points + state.mesh_displacement, mesh.quads, state.rho,
                    title=f"{name.replace('_', ' ')}: two-way compliance {figures['compliance']:.4g} J/m",
                    outlines=region_outlines(mesh.quads, mesh.region))
    base = runs["one_way_control"]["compliance_two_way"]
    summary = {"runs": runs, "compliance_change_vs_control_percent":
               {k: 100 * (v["compliance_two_way"] / base - 1) for k, v in runs.items()}}
    (output / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({k: {m: v[m] for m in v if m != "min_skewness_history"} for k, v in runs.items()}, indent=2))
    return summary


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("results/compare_mesh_motion"))
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    main(args.output)
