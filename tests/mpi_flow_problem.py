"""Run by ``mpiexec -n N``: a flow-only design problem evaluated by slabs (tofsi.parallel) at two
seeded random designs, every rank alike; rank 0 saves the objectives, constraints, their
gradients and the evaluations' gathered flow.

    mpiexec -n 2 python tests/mpi_flow_problem.py SCENE OUT.npz AMG [KEY=VALUE ...]
"""

import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.optimization.protocol import DesignProblem
from tofsi.parallel.flow_problem import DistributedFlowProblem

scene_path, out, amg, overrides = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
problem = DistributedFlowProblem(tofsi.load_scene(scene_path, [*overrides, f"solver.flow_amg={amg}"]))
assert isinstance(problem, DesignProblem)
rng = np.random.default_rng(5)
results = {}
for k in range(2):
    gamma = np.clip(0.5 + 0.25 * rng.standard_normal(problem.n_design), 0, 1)
    f, df = problem.evaluate(gamma)
    g, dg = problem.constraints(gamma)
    e = problem.evaluation(gamma)                        # the kept one: no second solve
    assert e.f == f and problem.evaluations == k + 1
    assert (e.state is None) == (PETSc.COMM_WORLD.getRank() != 0)
    results.update({f"gamma{k}": gamma, f"f{k}": f, f"df{k}": df, f"g{k}": g, f"dg{k}": dg})
    if e.state is not None:
        results[f"w{k}"] = e.state.w
if PETSc.COMM_WORLD.getRank() == 0:
    np.savez(out, **results)
