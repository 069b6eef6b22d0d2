"""Run by ``mpiexec -n N``: a flow objective and its density gradient by slabs (tofsi.parallel);
rank 0 saves them.

    mpiexec -n 2 python tests/mpi_flow_adjoint.py SCENE OUT.npz AMG [KEY=VALUE ...]

The densities: the scene's fixed regions, a seeded random gray design elsewhere.
"""

import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.parallel.flow_adjoint import SlabObjective
from tofsi.parallel.flow_system import DistributedFlow

scene_path, out, amg, overrides = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
problem = tofsi.Problem(tofsi.load_scene(scene_path, overrides))
rho = problem.model.densities()
rng = np.random.default_rng(3)
rho = np.where(rho == 1, 1.0, np.clip(0.3 + 0.3 * rng.standard_normal(rho.size), 0, 1))
engine = DistributedFlow(problem.model.flow, amg=amg)
report = engine.solve(None, rho, problem.params)
f, df = SlabObjective(engine, problem.objective).gradient(rho, problem.params)
if PETSc.COMM_WORLD.getRank() == 0:
    np.savez(out, f=f, df=df, rho=rho, newton=report["newton_iterations"], krylov=report["krylov_iterations"],
             transposed=engine.transposed_iterations)
