"""Where a coupled Jacobian was taken: the densities, the continuation numbers and the fields.

The monolithic Newton names each block Jacobian it builds by its point
(:attr:`tofsi.linalg.BlockMatrix.origin`), and the block preconditioner's
factors keep the points their diagonal blocks were factorized at
(:attr:`tofsi.linalg.BlockGaussSeidel.origins`). A point is everything the
diagonal blocks are a function of, for a given block system (the mesh, the
scene and the stage's structure fix the system): linearizing the system's
blocks at it again gives the same matrices bit for bit, so the same factors
(sparse LU is deterministic). That is how the factors an optimization carries
from one design to the next are saved (by their points) and made again on
resume (:mod:`tofsi.optimization.carried_factors`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofsi.core.blocks import Continuation
from tofsi.linalg import BlockMatrix


@dataclass(frozen=True, eq=False)
class JacobianPoint:
    """The point of a coupled Jacobian: physical densities ``rho`` (E,), the continuation
    numbers ``params`` (those the Newton solved with: a ramp's step has its own inflow) and the
    ``fields`` (name -> values, copies) it was linearized at."""

    rho: np.ndarray
    params: Continuation
    fields: dict

    @classmethod
    def at(cls, rho, params: Continuation, fields: dict) -> "JacobianPoint":
        """The point of ``fields`` (copied: the caller's dict goes on changing)."""
        return cls(np.array(rho, dtype=float), params,
                   {k: np.array(v, dtype=float) for k, v in fields.items() if v is not None})

    def jacobian(self, system, comp: tuple[str, ...]) -> BlockMatrix:
        """The block Jacobian of the cycle ``comp`` of ``system`` at this point (with its exact
        couplings), named by it."""
        lins = {n: system.by_name[n].linearize(self.fields, self.rho, self.params) for n in comp}
        return system.block_jacobian(lins, comp, at=self)
