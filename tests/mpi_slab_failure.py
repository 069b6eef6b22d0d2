"""Run by ``mpiexec -n N``: a mesh move by slabs (tofsi.parallel) that is to fail, every rank alike.

The wall design of ``tests/mpi_slab_mover.py`` bent downstream by ``AMPLITUDE`` metres (its
0.08 m bend scaled), ``u`` multiplied by ``NAN_FACTOR`` (1 unless given: ``nan`` makes the
motion non-finite). Each rank writes ``OUT.rank<r>.json``: the NumericalError's message and
diagnostic (its report and quality record, JSON), or ``{"x_norm": ...}`` where the move
succeeded; then the same mover moves once more to the 0.08 m bend (a coupled solve's cutback
after a failure) and rank 0 saves that motion ``x`` with ``rho`` and ``u`` to ``OUT.npz``; last
all ranks meet in a barrier, so a rank left inside a collective call shows as the caller's timeout.

    mpiexec -n 2 python tests/mpi_slab_failure.py SCENE OUT AMPLITUDE NAN_FACTOR [KEY=VALUE ...]
"""

import json
import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.core.errors import NumericalError
from tofsi.coupling.coupled import continuation
from tofsi.parallel.fsi_problem import DistributedFsiProblem

scene_path, out, amplitude, factor, overrides = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), sys.argv[5:]
scene = tofsi.load_scene(scene_path, overrides)
problem = DistributedFsiProblem(scene)
problem.set_stage(continuation(scene, scene.design.n_stages - 1))
mesh = problem.model.mesh
centroids = mesh.centroids[problem.map.design]
wall = (np.abs(centroids[:, 0] - 1.0) < 0.15) & (centroids[:, 1] < 0.6)
rho = problem.serial.densities(np.where(wall, 0.9, 0.1))
X, Y = mesh.points[:, 0], mesh.points[:, 1]
bend = np.column_stack([(Y / 0.6) ** 2 * np.exp(-((X - 1.0) / 0.3) ** 2), 0.0 * X]).ravel()
comm = PETSc.COMM_WORLD
try:
    x, _, report = problem.mover.move(amplitude * factor * bend, rho)
    record = {"x_norm": float(np.linalg.norm(x)), "report": report}
except NumericalError as err:
    record = {"message": str(err), "diagnostic": err.diagnostic}
with open(f"{out}.rank{comm.getRank()}.json", "w") as f:
    json.dump(record, f, default=str, sort_keys=True)
again, _, _ = problem.mover.move(0.08 * bend, rho)
if comm.getRank() == 0:
    np.savez(out + ".npz", rho=rho, u=0.08 * bend, x=again)
comm.barrier()
