"""Run by ``mpiexec -n N``: the flow solved by slabs and its transposed solve, repeated; each
rank's resident set after every repetition (the freed heap returned first: ``gc.collect`` and
glibc's ``malloc_trim``), gathered and saved by rank 0 (MB, shape (ranks, repetitions)).

    mpiexec -n 2 python tests/mpi_flow_memory.py OUT.npz REPETITIONS [KEY=VALUE ...]
"""

import ctypes
import gc
import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.parallel.flow_system import DistributedFlow

out, repetitions, overrides = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
libc = ctypes.CDLL("libc.so.6")


def resident_mb() -> float:
    gc.collect()
    libc.malloc_trim(0)
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) / 1e3 for line in fh if line.startswith("VmRSS"))


scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml", overrides)
model = tofsi.Problem(scene).model
rho = model.densities()
rho = np.where(rho == 1, 1.0, 0.5)
engine = DistributedFlow(model.flow, amg="hypre")
resident = []
for k in range(repetitions):
    engine.solve(None, rho, warm=k > 0)
    b = engine.mat.createVecLeft()
    b.set(1.0)
    engine.solve_transpose(b).destroy()
    b.destroy()
    engine.release_transpose()
    resident.append(resident_mb())
comm = PETSc.COMM_WORLD.tompi4py()
table = comm.gather(resident, root=0)
if comm.rank == 0:
    np.savez(out, resident=np.array(table))
