"""The block factors one design's two-way solve leaves, carried into the next design's Newton.

Consecutive designs of an optimization differ little, so the block
Gauss-Seidel preconditioner of the last design's Newton and adjoint (the
flow's, the structure's and the mesh's LU, :class:`tofsi.linalg.BlockGaussSeidel`)
still preconditions the next design's Jacobians well: the next Newton starts
from them (:meth:`tofsi.linalg.RecyclingSolver.with_factorize`) and makes new
ones only when they go stale (the solver's own rule: a GMRES solve that takes
more iterations beyond a fresh preconditioner's than a factorization costs).
Measured on the large scene at 80 x 40: flow factorizations per warm two-way
iteration 1.0 -> 0.25 (benchmarks/README.md, issue 32 item 1).

A carried preconditioner changes only the Krylov iterations, not the answer's
tolerance; but the last bits of a state depend on it, so a resumed run must
start from the same factors as the uninterrupted one. They are a function of
what they were factorized from: each diagonal block's
:class:`~tofsi.coupling.jacobian_point.JacobianPoint` (densities, continuation
numbers, fields; :attr:`BlockGaussSeidel.origins`), the block system (fixed by
the mesh, the scene and the stage) and the solver's measured fresh cost. The
checkpoint records that key (:meth:`CarriedFactors.record`) and a resume makes
the factors again from it (:func:`restore`; LU is deterministic, so they are
bitwise the same). Factors are carried only within their stage (a new stage,
a bridge or another structure model starts afresh) and only when every block
names its point.
"""

from __future__ import annotations

from dataclasses import asdict


from tofsi.core.blocks import Continuation, Stage
from tofsi.coupling.jacobian_point import JacobianPoint
from tofsi.linalg import BlockGaussSeidel, RecyclingSolver


class CarriedFactors:
    """The linear solver of the two-way cycle ``comp`` that the last design's solve left (after
    its adjoint), at continuation ``stage``; the optimizer's problem owns it
    (:attr:`tofsi.optimization.problem.Problem.factors`)."""

    def __init__(self, stage: Stage, comp: tuple[str, ...], solver: RecyclingSolver):
        self.stage, self.comp, self.solver = stage, tuple(comp), solver

    @classmethod
    def of(cls, state, stage: Stage) -> "CarriedFactors | None":
        """The factors a solved ``state`` leaves (None: one-way, no block preconditioner)."""
        for comp, coupled in state.coupled.items():
            if isinstance(coupled.solver, RecyclingSolver):
                return cls(stage, comp, coupled.solver)
        return None

    def preconditioner(self) -> BlockGaussSeidel | None:
        """The block preconditioner to carry: fresh enough and every block's point known."""
        pre = self.solver.solver
        if self.solver.stale or not isinstance(pre, BlockGaussSeidel):
            return None
        if any(not isinstance(o, JacobianPoint) for o in pre.origins):
            return None
        return pre

    def for_stage(self, stage: Stage) -> dict | None:
        """``{comp: solver}`` for the next solve at ``stage`` (None: another stage, or nothing
        to carry)."""
        if stage != self.stage or self.preconditioner() is None:
            return None
        return {self.comp: self.solver}

    def record(self) -> tuple[dict, dict] | None:
        """The key the factors are made again from: ``(table, arrays)`` for a checkpoint (the
        blocks' distinct points, each block's point, the fresh cost, the stage; the points'
        densities and fields as arrays), or None when there is nothing to carry."""
        pre = self.preconditioner()
        if pre is None:
            return None
        points: list[JacobianPoint] = []
        for o in pre.origins:
            if not any(o is p for p in points):
                points.append(o)
        arrays = {}
        for k, p in enumerate(points):
            arrays[f"factors{k}_rho"] = p.rho
            arrays.update({f"factors{k}_field_{name}": v for name, v in p.fields.items()})
        table = {"comp": list(self.comp), "fresh_cost": self.solver.fresh_cost,
                 "blocks": [next(k for k, p in enumerate(points) if o is p) for o in pre.origins],
                 "points": [{"params": asdict(p.params), "fields": list(p.fields)} for p in points]}
        return table, arrays


def restore(table: dict | None, arrays: dict, stage: Stage, system) -> CarriedFactors | None:
    """The factors of a checkpoint's :meth:`CarriedFactors.record` made again, on ``system`` (the
    block system of ``stage``, the checkpoint's): the Jacobian at the largest block's point
    factorized whole, then the small blocks refactorized from the Jacobian at theirs where it is
    another, as the run made them (:meth:`BlockGaussSeidel.refactor_small_blocks`); None for no
    record."""
    if table is None:
        return None
    comp = tuple(table["comp"])
    points = [JacobianPoint(arrays[f"factors{k}_rho"], Continuation(**p["params"]),
                            {name: arrays[f"factors{k}_field_{name}"] for name in p["fields"]})
              for k, p in enumerate(table["points"])]
    blocks = table["blocks"]
    sizes = [system.by_name[n].size for n in comp]
    first = blocks[sizes.index(max(sizes))]
    solver = system.linear_solver(comp)
    solver.refresh(points[first].jacobian(system, comp))
    later = {k for k in blocks if k != first}
    if len(later) > 1:
        raise ValueError(f"the checkpoint's factors name blocks {blocks} that one refactorization "
                         "of the small ones cannot make")
    for k in later:
        refactorized = solver.solver.refactor_small_blocks(points[k].jacobian(system, comp))
        if [i for i, b in enumerate(blocks) if b == k] != refactorized:
            raise ValueError(f"the checkpoint's factors name blocks {blocks} that a refactorization "
                             f"of the small ones ({refactorized}) cannot make")
    solver.fresh_cost = table["fresh_cost"]
    return CarriedFactors(stage, comp, solver)
