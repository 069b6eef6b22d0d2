"""Linear solvers: sparse direct backends with reused analysis, AMG, and recycling.

* :class:`LinearAlgebra` -- a model's backend and threads, from its scene's ``[solver]``;
* :class:`DirectSolver` -- sparse LU on a backend chosen by name
  (:mod:`tofsi.linalg.backends`: ``superlu`` always, ``pardiso`` and ``petsc``
  when installed, ``auto`` the fastest), the pattern analysed once;
* :class:`AMGSolver` -- smoothed-aggregation AMG with CG for SPD systems;
* :class:`BlockMatrix` -- a coupled Jacobian kept as its field blocks (products, no assembly);
* :class:`BlockGaussSeidel` -- a field-block matrix preconditioned by its block lower
  triangle, the fields' own factorizations (coupled Jacobians);
* :class:`RecyclingSolver` -- a sequence of slowly changing systems, solved by
  Krylov iterations preconditioned with an earlier factorization or AMG hierarchy;
* :func:`nested_dissection` -- the grid ordering that keeps LU fill low.
"""

from __future__ import annotations

from tofsi.linalg.amg import AMGSolver, rigid_body_modes
from tofsi.linalg.block_gauss_seidel import BlockGaussSeidel
from tofsi.linalg.block_matrix import BlockMatrix
from tofsi.linalg.backends import available, get_backend, set_default
from tofsi.linalg.choice import LinearAlgebra
from tofsi.linalg.direct import DirectSolver
from tofsi.linalg.ordering import nested_dissection
from tofsi.linalg.recycling import RecyclingSolver

__all__ = ["AMGSolver", "BlockGaussSeidel", "BlockMatrix", "DirectSolver", "LinearAlgebra", "RecyclingSolver", "available",
           "get_backend", "make_solver",
           "nested_dissection", "rigid_body_modes", "set_default"]


def make_solver(A, kind: str = "direct", coords=None, near_null=None, tol=1e-10,
                perm=None, symmetric: bool = True, linear_algebra: LinearAlgebra | None = None):
    """A reusable solver of kind ``direct`` (LU on the backend of ``linear_algebra``, else the
    process default) or ``amg`` (SPD systems only).

    perm : a precomputed fill-reducing permutation (else computed from ``coords``)
    """
    if kind == "direct":
        if linear_algebra is not None:
            return linear_algebra.direct(A, perm=perm if perm is not None or coords is None
                                         else nested_dissection(coords))
        return DirectSolver(A, coords=coords, perm=perm)
    if kind == "amg":
        return AMGSolver(A, near_null=near_null, tol=tol, symmetric=symmetric)
    raise ValueError(f"unknown linear solver {kind!r}")
