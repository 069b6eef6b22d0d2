"""The same two-way design problem with each mesh mover: compliance, mesh quality, time.

Runs ``optimize_fsi.py`` three times -- Yeoh hyperelastic, linear elasticity
(Jacobian-stiffened) and the spring analogy -- and tabulates, for each, the
final design's compliance (two-way), the smallest element skewness of the
moved mesh over the whole run, and the wall time; the designs and their
convergence plots are side by side in the output folder. About four minutes
on two cores:

    python examples/compare_movers.py [--output results/compare_movers]

``TOFSI_EXAMPLE_SMALL=1`` runs each at the small size (the test suite does this).
"""

import argparse
import json
from pathlib import Path

from optimize_fsi import main as optimize_fsi

MOVERS = ("yeoh", "linear", "spring")


def main(output: Path, overwrite: bool = False) -> list[dict]:
    rows = []
    for mover in MOVERS:
        print(f"--- {mover} mover")
        result = optimize_fsi(output / mover, [f"mover.name={mover}"], overwrite)
        rows.append({"mover": mover, "compliance": result["objective"], "volume": result["volume"],
                     "min_skewness": result["min_skewness_over_run"],
                     "max_displacement": result["max_displacement"], "wall_time_s": result["wall_time_s"]})
    lines = ["| mover | compliance [J/m] | min skewness over the run | largest displacement [m] | time [s] |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['mover']} | {r['compliance']:.4g} | {r['min_skewness']:.3f} | "
              f"{r['max_displacement']:.3g} | {r['wall_time_s']:.0f} |" for r in rows]
    table = "\n".join(lines) + "\n"
    (output / "movers.md").write_text(table)
    (output / "movers.json").write_text(json.dumps(rows, indent=2))
    print(table)
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("results/compare_movers"))
    parser.add_argument("--overwrite", action="store_true", help="replace other runs' files in --output")
    args = parser.parse_args()
    main(args.output, args.overwrite)
