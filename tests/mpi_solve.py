"""Run by ``mpiexec -n N``: the coupled solve with the petsc backend; rank 0 saves the state.

    mpiexec -n 2 python tests/mpi_solve.py OUT.npz [--set KEY=VALUE ...]
"""

import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.coupling.coupled import CoupledModel
from tofsi.linalg import backends

out, overrides = sys.argv[1], sys.argv[2:]
scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml",
                         ["solver.linear_solver=petsc", *overrides])
model = CoupledModel(scene)
state = model.solve(model.densities())
rows = backends.get_backend("petsc").local_rows          # of the last factorization
counts = PETSc.COMM_WORLD.tompi4py().gather(rows, root=0)
if PETSc.COMM_WORLD.getRank() == 0:
    np.savez(out, w=state.w, u=state.u, ranks=PETSc.COMM_WORLD.getSize(), rows=np.array(counts),
             analyses=backends.get_backend("petsc").analyses)
