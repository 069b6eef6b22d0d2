"""Run by ``mpiexec -n N``: the mesh mover by slabs (tofsi.parallel.slab_mover) at the last
continuation stage of an FSI scene, at the wall design of ``tests/mpi_fsi_problem.py`` (no
noise) and a prescribed structural displacement bending the wall downstream; every rank
alike. Rank 0 saves the motion ``x``, its report's counts, and for a seeded random ``rhs``
the transposed solve ``lam = D_x^-T rhs`` and the transposed partials ``lam^T D_u``,
``lam^T D_rho``; for a mover in increments also the tangent sweep ``x_dot`` along a seeded
random ``u_dot`` and the reverse sweep of ``rhs`` (``u_bar``, ``rho_bar`` of ``x = M(u, rho)``,
twice: after the first sweep, the mover moves again to another motion and the move's matrices
are assembled anew). When the move fails, each rank writes its message to ``OUT.rank<r>.txt``.

    mpiexec -n 2 python tests/mpi_slab_mover.py SCENE OUT.npz [KEY=VALUE ...]
"""

import sys

import numpy as np
from petsc4py import PETSc

from mpi_wall import wall_problem
from tofsi.core.errors import NumericalError

scene_path, out, overrides = sys.argv[1], sys.argv[2], sys.argv[3:]
problem, rho, bend = wall_problem(scene_path, overrides)
u = 0.08 * bend
rank = PETSc.COMM_WORLD.getRank()
try:
    x, lin, report = problem.mover.move(u, rho)
except NumericalError as err:
    with open(f"{out}.rank{rank}.txt", "w") as f:
        f.write(str(err))
    sys.exit(0)
rhs = np.random.default_rng(3).standard_normal(x.size)
lam = lin.solve_transpose(rhs)
bars, rho_bar = lin.transpose_partials(lam)
sweeps = {}
if problem.mover.incremental:
    u_dot = np.random.default_rng(4).standard_normal(x.size)
    sweeps["u_dot"], sweeps["x_dot"] = u_dot, lin.jvp(u_dot)
    sweeps["vjp_u"], sweeps["vjp_rho"] = lin.vjp(rhs)
    problem.mover.move(0.5 * u, rho)                      # another move on the same matrices
    sweeps["again_u"], sweeps["again_rho"] = lin.vjp(rhs)
if rank == 0:
    np.savez(out, rho=rho, u=u, x=x, rhs=rhs, lam=lam, u_bar=bars["u"], rho_bar=rho_bar,
             newton=report["newton_iterations"], increments=report["increments"],
             factorizations=report["factorizations"], **sweeps)
