"""One two-way evaluation of the headline FSI scene on P MPI ranks (tofsi.parallel): wall, CPU, peak per rank.

Run in the PETSc environment (``docs/parallel.md``), as root with the Open MPI flag:

    mpiexec --allow-run-as-root -n 2 /work/venv-petsc/bin/python -m benchmarks.distributed_fsi \
        --elements-x 160 [--h 0.00884] [--amg hypre] [--set mover.name=spring --set mover.spring.increments=10]

``examples/scenes/beam_in_channel_optimization_fsi.toml`` at ``--elements-x`` elements along
the channel (half as many across), its last continuation stage (two-way, beta 16, the Yeoh
mover with its stiffened layers), the wall design of ``tests/mpi_fsi_problem.py`` without its
noise (density 0.9 in ``|x - 1| < 0.15``, ``y < 0.6``, 0.1 elsewhere), solved from rest and
differentiated once (:class:`tofsi.parallel.fsi_problem.DistributedFsiProblem`: the flow and
the structure and the Yeoh mover by slabs; ``--set`` changes the scene, e.g. the spring
analogy in increments, by slabs too). Each rank prints one line: the setup and
evaluation wall times, its process CPU seconds and its peak resident memory
(``ru_maxrss``) in GB, and the compliance.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization_fsi.toml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=80)
    parser.add_argument("--h", type=float, default=None, help="element size [m] (default: 2 / elements-x)")
    parser.add_argument("--amg", default="hypre", choices=["gamg", "hypre"])
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    args = parser.parse_args()
    import numpy as np
    from petsc4py import PETSc

    import tofsi
    from tofsi.coupling.coupled import continuation
    from tofsi.parallel.fsi_problem import DistributedFsiProblem
    t0, c0 = time.perf_counter(), time.process_time()
    h = 2.0 / args.elements_x if args.h is None else args.h
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h!r}", f"mesh.h_max={h!r}", f"solver.flow_amg={args.amg}", *args.set])
    problem = DistributedFsiProblem(scene)
    problem.set_stage(continuation(scene, scene.design.n_stages - 1))
    centroids = problem.model.mesh.centroids[problem.map.design]
    wall = (np.abs(centroids[:, 0] - 1.0) < 0.15) & (centroids[:, 1] < 0.6)
    t1 = time.perf_counter()
    f, _ = problem.evaluate(np.where(wall, 0.9, 0.1))
    t2 = time.perf_counter()
    comm = PETSc.COMM_WORLD
    print(f"rank {comm.getRank()}/{comm.getSize()}: {problem.model.mesh.n_elements} elements, setup {t1 - t0:.1f} s, "
          f"evaluation {t2 - t1:.1f} s wall, {time.process_time() - c0:.1f} s CPU, peak "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB, compliance {f:.10g}", flush=True)


if __name__ == "__main__":
    main()
