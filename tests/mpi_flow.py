"""Run by ``mpiexec -n N``: the flow solved by slabs (tofsi.parallel); rank 0 saves the state.

    mpiexec -n 2 python tests/mpi_flow.py OUT.npz AMG [--set KEY=VALUE ...]
"""

import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.parallel.flow_system import DistributedFlow

out, amg, overrides = sys.argv[1], sys.argv[2], sys.argv[3:]
scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml", overrides)
model = tofsi.Problem(scene).model
rho = model.densities()
rng = np.random.default_rng(3)
rho = np.where(rho == 1, 1.0, np.clip(0.3 + 0.3 * rng.standard_normal(rho.size), 0, 1))
engine = DistributedFlow(model.flow, amg=amg)
report = engine.solve(None, rho)
w = engine.gather()
comm = PETSc.COMM_WORLD.tompi4py()
elements = comm.gather(int(engine.part.elements.size), root=0)
if comm.rank == 0:
    np.savez(out, w=w, rho=rho, ranks=comm.size, elements=np.array(elements),
             krylov=report["krylov_iterations"], newton=report["newton_iterations"])
