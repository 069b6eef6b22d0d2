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

from mpi_wall import wall_problem
from tofsi.core.errors import NumericalError

scene_path, out, amplitude, factor, overrides = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), sys.argv[5:]
problem, rho, bend = wall_problem(scene_path, overrides)
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
