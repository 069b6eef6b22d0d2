"""The flow solved by slabs on P MPI ranks (tofsi.parallel, PETSc): wall time and peak memory per rank.

Run in the PETSc environment (``docs/parallel.md``), as root with the Open MPI flag:

    mpiexec --allow-run-as-root -n 2 /work/venv-petsc/bin/python -m benchmarks.distributed_flow \
        --elements-x 720 [--amg hypre]

The beam-in-channel scene at ``--elements-x`` elements along the channel
(half as many across), the projected random design of
``benchmarks/iterative_flow.py`` (beta 4), Navier-Stokes at the scene's
Reynolds number, Newton from the boundary values to the scene's tolerance.
Rank 0 prints one line: ranks, elements, unknowns, Newton and Krylov
iterations, the setup (mesh, partition, PETSc objects) and solve wall
times, and every rank's peak resident memory (``ru_maxrss``) in GB. With
``--adjoint`` also the gradient of the dissipation functional in the
densities (:class:`tofsi.parallel.flow_adjoint.SlabObjective`: the
transposed fieldsplit solve to 1e-11 and the slab's element sums): its
FGMRES iterations and wall time.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization.toml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=180)
    parser.add_argument("--amg", default="hypre", choices=["gamg", "hypre"])
    parser.add_argument("--adjoint", action="store_true", help="time the dissipation's gradient too")
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks"))
    args = parser.parse_args()
    from petsc4py import PETSc

    import tofsi
    from benchmarks.iterative_flow import design
    from tofsi.mesh.channel import build_mesh
    from tofsi.parallel.flow_system import DistributedFlow
    from tofsi.physics.flow import Flow
    from tofsi.linalg.threads import set_blas_threads
    set_blas_threads(1)
    comm = PETSc.COMM_WORLD.tompi4py()
    t0 = time.perf_counter()
    h = 2.0 / args.elements_x
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}"])
    flow = Flow(build_mesh(scene.geometry, scene.mesh), scene.fluid)      # the flow alone: no filter, no structure
    rho = design(flow.mesh, 4.0)
    engine = DistributedFlow(flow, amg=args.amg)
    comm.Barrier()
    t1 = time.perf_counter()
    report = engine.solve(None, rho)
    comm.Barrier()
    t2 = time.perf_counter()
    adjoint = {}
    if args.adjoint:
        from tofsi.parallel.flow_adjoint import SlabObjective
        from tofsi.core.registry import OBJECTIVES
        SlabObjective(engine, OBJECTIVES.get("dissipation")()).gradient(rho, None)
        comm.Barrier()
        adjoint = {"adjoint_krylov": engine.transposed_iterations, "adjoint_s": time.perf_counter() - t2}
    peaks = comm.gather(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2, root=0)
    if comm.rank == 0:
        row = {"ranks": comm.size, "elements": flow.mesh.n_elements, "unknowns": flow.size,
               "amg": args.amg, "newton": report["newton_iterations"], "krylov": report["krylov_iterations"],
               "setup_s": t1 - t0, "solve_s": t2 - t1, **adjoint, "peak_gb_per_rank": peaks}
        print(f"ranks {row['ranks']}  elements {row['elements']}  unknowns {row['unknowns']}  {args.amg}  "
              f"Newton {row['newton']}  Krylov {row['krylov']}  setup {row['setup_s']:.1f} s  "
              f"solve {row['solve_s']:.1f} s  "
              + (f"adjoint {row['adjoint_krylov']} its {row['adjoint_s']:.1f} s  " if adjoint else "")
              + f"peak GB per rank {' '.join(f'{p:.2f}' for p in peaks)}",
              flush=True)
        args.output.mkdir(parents=True, exist_ok=True)
        path = args.output / "distributed_flow.jsonl"
        with path.open("a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
