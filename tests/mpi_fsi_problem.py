"""Run by ``mpiexec -n N``: a compliance FSI design problem with the flow by slabs (tofsi.parallel)
evaluated at continuation stage STAGE at two designs (a wall of width 0.3 m, then 0.4 m, up to
0.6 m high at the channel's middle, density 0.9 in 0.1, with seeded noise; the second warm-started
from the first), every rank alike; rank 0 saves the objectives, constraints, their gradients and the
states (flow gathered on rank 0, structure and mesh motion).

    mpiexec -n 2 python tests/mpi_fsi_problem.py SCENE OUT.npz AMG STAGE [KEY=VALUE ...]
"""

import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.coupling.coupled import continuation
from tofsi.optimization.protocol import DesignProblem
from tofsi.parallel.fsi_problem import DistributedFsiProblem

scene_path, out, amg, stage, overrides = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5:]
scene = tofsi.load_scene(scene_path, [*overrides, f"solver.flow_amg={amg}"])
problem = DistributedFsiProblem(scene)
assert isinstance(problem, DesignProblem)
problem.set_stage(continuation(scene, stage))
rng = np.random.default_rng(7)
centroids = problem.model.mesh.centroids[problem.map.design]
results = {}
for k in range(2):
    wall = (np.abs(centroids[:, 0] - 1.0) < 0.15 + 0.05 * k) & (centroids[:, 1] < 0.6)
    gamma = np.clip(np.where(wall, 0.9, 0.1) + 0.05 * rng.standard_normal(problem.n_design), 0, 1)
    f, df = problem.evaluate(gamma)
    g, dg = problem.constraints(gamma)
    e = problem.evaluation(gamma)                        # the kept one: no second solve
    assert e.f == f and problem.evaluations == k + 1
    results.update({f"gamma{k}": gamma, f"f{k}": f, f"df{k}": df, f"g{k}": g, f"dg{k}": dg})
    if e.state is not None:
        results.update({f"{name}{k}": value for name, value in e.state.fields.items()})
if PETSc.COMM_WORLD.getRank() == 0:
    np.savez(out, **results)
