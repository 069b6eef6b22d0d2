"""Linear solvers: sparse direct backends with reused analysis, AMG, and recycling.

* :class:`LinearAlgebra` -- a model's backend and threads, from its scene's ``[solver]``;
* :class:`DirectSolver` -- sparse LU on a backend chosen by name
  (:mod:`tofsi.linalg.backends`: ``superlu`` always, ``pardiso`` and ``petsc``
  when installed, ``auto`` the fastest), the pattern analysed once;
* :class:`AMGSolver` -- smoothed-aggregation AMG with CG for SPD systems;
* :class:`BlockMatrix` -- a coupled Jacobian kept as its field blocks (products, no assembly),
  a block possibly a :class:`LinearMap` (known by its products only);
* :class:`BlockGaussSeidel` -- a field-block matrix preconditioned by its block lower
  triangle, the fields' own factorizations (coupled Jacobians);
* :class:`RecyclingSolver` -- a sequence of slowly changing systems, solved by
  Krylov iterations preconditioned with an earlier factorization or AMG hierarchy;
* :func:`nested_dissection` -- the grid ordering that keeps LU fill low.
"""

from __future__ import annotations

from tofsi.linalg.amg import AMGSolver, rigid_body_modes
from tofsi.linalg.block_gauss_seidel import BlockGaussSeidel
from tofsi.linalg.block_matrix import BlockMatrix, LinearMap
from tofsi.linalg.backends import available, get_backend, set_default
from tofsi.linalg.choice import LinearAlgebra
from tofsi.linalg.direct import DirectSolver
from tofsi.linalg.ordering import nested_dissection
from tofsi.linalg.recycling import RecyclingSolver

__all__ = ["AMGSolver", "BlockGaussSeidel", "BlockMatrix", "DirectSolver", "LinearAlgebra", "LinearMap",
           "RecyclingSolver",
           "available", "get_backend", "nested_dissection", "rigid_body_modes", "set_default"]

