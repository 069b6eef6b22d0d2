"""The mesh mover alone on P MPI ranks: by slabs against replicated, its peak memory per rank.

Run in the PETSc environment (``docs/parallel.md``), as root with the Open MPI flag:

    mpiexec --allow-run-as-root -n 2 /work/venv-petsc/bin/python -m benchmarks.distributed_mover \
        --elements-x 140 --mover slabs|replicated [--set mover.name=spring --set mover.spring.increments=10]

``examples/scenes/beam_in_channel_optimization_fsi.toml`` at ``--elements-x`` elements along
the channel, its last continuation stage (the Yeoh mover, density blend, stiffened layers grown
from the densities; ``--set`` changes the scene, e.g. a mover in increments), the wall design of ``benchmarks/distributed_fsi.py`` and a prescribed
structural displacement bending the wall 8 cm downstream (``tests/mpi_slab_mover.py``'s). One
move from rest, one transposed solve and the transposed partials (a mover in increments: the
reverse sweep), either by slabs (:class:`tofsi.parallel.slab_mover.SlabMover`,
:class:`tofsi.parallel.slab_increments.SlabIncrementMover`) or replicated (the serial
:class:`~tofsi.physics.mesh_motion.MeshMotion` on every rank, as the distributed FSI problem
ran it before). Each rank prints its process CPU seconds of the mover's work, its peak
resident memory (``ru_maxrss``) after the setup and after the mover's work, and the mover's own
high-water mark: the resident set sampled every 5 ms during the work above the resident set at
its start (the heap's free pages given back first, ``malloc_trim``), in GB.
"""

from __future__ import annotations

import argparse
import os
import resource
import threading
import time
from pathlib import Path

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization_fsi.toml"


def peak() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def resident() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e9


class Sampler(threading.Thread):
    """The largest resident set seen every 5 ms until stopped [GB]."""

    def __init__(self):
        super().__init__(daemon=True)
        self.high, self.running = resident(), True

    def run(self):
        while self.running:
            self.high = max(self.high, resident())
            time.sleep(0.005)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=80)
    parser.add_argument("--mover", default="slabs", choices=["slabs", "replicated"])
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    args = parser.parse_args()
    import numpy as np
    from petsc4py import PETSc

    import tofsi
    from tofsi.coupling.coupled import continuation
    from tofsi.parallel.fsi_problem import DistributedFsiProblem
    h = 2.0 / args.elements_x
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h!r}", f"mesh.h_max={h!r}", *args.set])
    problem = DistributedFsiProblem(scene)
    problem.set_stage(continuation(scene, scene.design.n_stages - 1))
    mesh, motion = problem.model.mesh, problem.model.motion
    centroids = mesh.centroids[problem.map.design]
    wall = (np.abs(centroids[:, 0] - 1.0) < 0.15) & (centroids[:, 1] < 0.6)
    rho = problem.serial.densities(np.where(wall, 0.9, 0.1))
    X, Y = mesh.points[:, 0], mesh.points[:, 1]
    u = np.column_stack([0.08 * (Y / 0.6) ** 2 * np.exp(-((X - 1.0) / 0.3) ** 2), 0.0 * X]).ravel()
    rhs = np.random.default_rng(3).standard_normal(u.size)
    from tofsi.linalg.superlu import release_free_pages
    release_free_pages()
    start = resident()
    sampler = Sampler()
    sampler.start()
    before, c0, t0 = peak(), time.process_time(), time.perf_counter()
    if args.mover == "slabs":
        x, lin, _ = problem.mover.move(u, rho)
        lam = lin.solve_transpose(rhs)
        _, rho_bar = lin.transpose_partials(lam)
    elif motion.path_dependent:
        result = motion.move(u, rho)
        x = result.displacement.ravel()
        _, rho_bar = motion.vjp(result, rhs.reshape(-1, 2), rho)
    else:
        x = motion.move(u, rho).displacement.ravel()
        lam = motion.transposed_solve(x, rho, rhs)
        _, rho_bar = motion.partials_transpose(x, u, rho, lam)
    cpu, wall_time = time.process_time() - c0, time.perf_counter() - t0
    sampler.running = False
    sampler.join()
    comm = PETSc.COMM_WORLD
    print(f"rank {comm.getRank()}/{comm.getSize()} {args.mover}: {mesh.n_elements} elements, mover {wall_time:.1f} s "
          f"wall, {cpu:.1f} s CPU, peak {before:.3f} GB after setup, {peak():.3f} GB after the mover "
          f"(+{peak() - before:.3f}), the mover's own +{sampler.high - start:.3f} GB, |x| {np.linalg.norm(x):.12g}, |rho_bar| {np.linalg.norm(rho_bar):.12g}",
          flush=True)


if __name__ == "__main__":
    main()
