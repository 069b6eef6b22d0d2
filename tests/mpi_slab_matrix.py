"""Run by ``mpiexec -n N``: a :class:`tofsi.parallel.slab_matrix.SlabMatrix` whose factorization
fails, then recovers. Linear elasticity's element matrices on each rank's quads of the FSI
scene's moving mesh (the mover of ``tests/mpi_slab_mover.py``), assembled with one quad's matrix
NaN on the last rank only: the solve (with ``rtol``, as a move's increments solve) fails on every
rank alike; the same matrix assembled right then solves with ``rtol`` and exactly. Each rank
writes ``OUT.rank<r>.json``: per step the error message or the relative difference from a
never-failed matrix's exact solve, and the factorization count.

    mpiexec -n 2 python tests/mpi_slab_matrix.py SCENE OUT [KEY=VALUE ...]
"""

import json
import sys

import numpy as np
from petsc4py import PETSc

import tofsi
from tofsi.core.errors import NumericalError
from tofsi.coupling.coupled import continuation
from tofsi.parallel.fsi_problem import DistributedFsiProblem

scene_path, out, overrides = sys.argv[1], sys.argv[2], sys.argv[3:]
scene = tofsi.load_scene(scene_path, overrides)
problem = DistributedFsiProblem(scene)
problem.set_stage(continuation(scene, scene.design.n_stages - 1))
mover = problem.mover
comm = PETSc.COMM_WORLD
K = mover.kernel()(mover.motion.base.points[mover.quads])
broken = K.copy()
if comm.getRank() == comm.getSize() - 1:
    broken[0] = np.nan
b = np.random.default_rng(1).standard_normal(mover.size)
reference = mover.new_matrix()
reference.assemble(mover.dofs, K)
want = reference.solve(b)
reference.assemble(mover.dofs, 2 * K)
want2 = reference.solve(b)
matrix = mover.new_matrix()
steps = {}
for label, Ke, rtol in (("broken", broken, 1e-8), ("again", K, 1e-8), ("exact", K, None), ("doubled", 2 * K, 1e-13)):
    if label == "doubled":                         # as at a new design: the kept factors expire
        matrix.expire()
    matrix.assemble(mover.dofs, Ke)
    try:
        x = matrix.solve(b, rtol=rtol)
        if label == "exact":                       # as a reverse sweep: the transposed solve too
            x = 0.5 * (x + matrix.solve(b, transpose=True))
        truth = want2 if label == "doubled" else want
        steps[label] = {"error": float(np.linalg.norm(x - truth) / np.linalg.norm(truth))}
    except NumericalError as err:
        steps[label] = {"message": str(err)}
    steps[label]["factorizations"] = matrix.factorizations
with open(f"{out}.rank{comm.getRank()}.json", "w") as f:
    json.dump(steps, f, sort_keys=True)
comm.barrier()
