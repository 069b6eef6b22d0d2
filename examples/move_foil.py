"""Move the mesh around a foil with each mover and compare the mesh quality.

The foil in a channel (Stein et al. 2003; Abdelhamid & Czekanski) is
translated, rotated or bent; every mover (spring analogy, linear
elasticity, Yeoh hyperelasticity) moves the fluid mesh, and we print the
worst skewness and area change. Run:

    python examples/move_foil.py [rotation|translation|bending] [--output DIR]

``TOFSI_EXAMPLE_SMALL=1`` uses a coarse mesh (the test suite does this).
"""

import argparse
import os
from pathlib import Path

import movers
import tofsi
from tofsi.core.errors import NumericalError
from tofsi.coupling.motion import moved_quality, motion_setup, run_move
from tofsi.runs.output import write_csv

HERE = Path(__file__).parent
MESH = ["mesh.h_min=0.05", "mesh.h_max=0.1"] if os.environ.get("TOFSI_EXAMPLE_SMALL", "0") != "0" else []


def main(mode: str = "rotation", output: Path = Path("results/move_foil")) -> list[dict]:
    scene = tofsi.load_scene(HERE / "scenes" / "foil_in_channel.toml", MESH + [f"deformation.mode={mode}"])
    setup = motion_setup(scene)             # the mesh and the foil's motion, shared by all movers
    print(f"foil {mode}: {setup.moving.size} moving quads")
    rows = []
    for name in movers.available():
        scene_m = tofsi.load_scene(scene.source, MESH + [f"deformation.mode={mode}", f"mover.name={name}"])
        try:
            _, result = run_move(scene_m, setup=setup)
            q = moved_quality(setup, result.displacement)
            row = {"mover": name, "min_skewness": q.min_skewness, "n_inverted": q.n_inverted,
                   "min_area_change": q.min_area_change, "max_area_change": q.max_area_change,
                   "time_s": result.report.wall_time_s}
        except NumericalError as err:        # e.g. linear elasticity inverting elements
            q = err.diagnostic["quality"]
            row = {"mover": name, "min_skewness": q["min_skewness"], "n_inverted": q["n_inverted"],
                   "min_area_change": q["min_area_change"], "max_area_change": q["max_area_change"],
                   "time_s": err.diagnostic["report"]["wall_time_s"]}
        rows.append(row)
        print(f"  {name:7s} min skewness {row['min_skewness']:7.3f}   inverted {row['n_inverted']:3d}"
              f"   area change {row['min_area_change']:.3f} .. {row['max_area_change']:.3f}"
              f"   {row['time_s']:.2f} s")
    write_csv(output / f"movers_{mode}.csv", rows)
    print(f"wrote {output / f'movers_{mode}.csv'}")
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", nargs="?", default="rotation", choices=["translation", "rotation", "bending"])
    parser.add_argument("--output", type=Path, default=Path("results/move_foil"))
    args = parser.parse_args()
    main(args.mode, args.output)
