"""An ordered set of field blocks, and the forward solve of the coupled problem they make.

The blocks' ``inputs`` draw a dependency graph. Its strongly connected
components, in topological order, are solved one after the other:

* a block that depends on nothing later is solved once (one-way coupling:
  the flow, then the structure loaded by it);
* a cycle (two-way coupling: flow -> structure -> mesh motion -> flow) is
  solved either

  - partitioned: Gauss-Seidel sweeps over its blocks in the system's order,
    the ``relax`` field's next value from the interface quasi-Newton method
    (:class:`~tofsi.core.iteration.InterfaceQuasiNewton`), until its relative
    change ``|z~ - z| / |z~|`` is at most ``tol``; the blocks before it in
    the sweep are then solved once more, so every field is consistent; or
  - monolithic: Newton on the block Jacobian ``[[dR_a/dz_b]]`` (every block of
    the cycle needs a residual form; a move in increments is the residual
    ``x - M(u)`` whose coupling is known by its products) with a backtracking
    line search, each step solved inexactly by :meth:`BlockSystem.linear_solver`
    (:mod:`tofsi.coupling.monolithic`).

Both report their history and raise :class:`~tofsi.core.errors.NumericalError`
when they do not converge. The system also gives the split of a stacked
vector into fields, the monolithic Jacobian and its fill-reducing ordering,
and the list of fields a checkpoint stores -- so adding a field is adding a
block.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tofsi.core.blocks import Continuation, FieldBlock, Linearization, State
from tofsi.core.errors import InputError, NumericalError
from tofsi.core.iteration import InterfaceQuasiNewton
from tofsi.linalg import BlockGaussSeidel, BlockMatrix, LinearAlgebra, LinearMap, RecyclingSolver, nested_dissection
from tofsi.linalg.backends import canonical_csr, resolve
from tofsi.coupling.monolithic import solve_monolithic

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CouplingSettings:
    """How cycles are solved: ``method`` partitioned or monolithic, tolerance, iterations,
    the first relaxation factor (partitioned), the relaxed field, and (monolithic) whether
    the shape couplings are kept (``quasi_newton``) and the Newton's ``jacobian_solver``."""

    method: str = "partitioned"
    tol: float = 1e-9
    max_iter: int = 60
    relaxation: float = 0.5
    relax: str | None = None
    quasi_newton: bool = True
    jacobian_solver: str = "block"


class BlockSystem:
    """Field blocks in a fixed order, their dependency components and the coupled solve.

    linear_algebra : the model's :class:`~tofsi.linalg.LinearAlgebra` for the monolithic
    Newton's factorizations (default: the process's backend)."""

    def __init__(self, blocks, settings: CouplingSettings | None = None,
                 linear_algebra: LinearAlgebra | None = None):
        self.blocks = tuple(blocks)
        self.settings = settings or CouplingSettings()
        self.linear_algebra = linear_algebra or LinearAlgebra(backend=resolve())
        self.names = tuple(b.name for b in self.blocks)
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"field names must be unique: {self.names}")
        self.by_name = {b.name: b for b in self.blocks}
        for b in self.blocks:
            unknown = set(b.inputs) - set(self.names)
            if unknown:
                raise ValueError(f"block {b.name!r} depends on fields no block provides: {sorted(unknown)}")
        self.components = self._components()
        if self.settings.method == "monolithic":
            for comp in self.cycles:
                explicit = [n for n in comp if not self.by_name[n].has_residual]
                if explicit:
                    raise InputError("coupled.method", "monolithic",
                                     f"field {explicit[0]!r} is an explicit (path-dependent) map "
                                     "without a residual form; use 'partitioned' or 'auto'")
        if self.settings.jacobian_solver == "direct":
            for comp in self.cycles:
                free = [n for n in comp if self.by_name[n].matrix_free_couplings]
                if free and self.method_for(comp) == "monolithic":
                    raise InputError("coupled.jacobian_solver", "direct",
                                     f"field {free[0]!r} gives its coupling by products only (a mover in "
                                     "increments on the updated mesh): the whole Jacobian cannot be "
                                     "factorized; use 'block'")
        sizes = [b.size for b in self.blocks]
        self.offsets = dict(zip(self.names, np.cumsum([0, *sizes])[:-1].astype(int), strict=True))
        self.size = int(sum(sizes))
        self._orderings: dict[tuple[str, ...], np.ndarray | None] = {}

    # ---- structure ------------------------------------------------------------------
    def _components(self) -> list[tuple[str, ...]]:
        """Strongly connected components of the dependency graph, in an order that solves
        every component after the ones it depends on (ties: the blocks' order)."""
        n = len(self.names)
        index = {name: i for i, name in enumerate(self.names)}
        reach = np.eye(n, dtype=bool)                  # reach[i, j]: i depends (transitively) on j
        for b in self.blocks:
            for other in b.inputs:
                reach[index[b.name], index[other]] = True
        for k in range(n):                              # Warshall's transitive closure
            reach |= reach[:, [k]] & reach[[k], :]
        comps, seen = [], set()
        for i, name in enumerate(self.names):
            if name not in seen:
                comp = tuple(self.names[j] for j in range(n) if reach[i, j] and reach[j, i])
                comps.append(comp)
                seen.update(comp)
        ordered, done = [], set()
        while comps:
            for comp in comps:
                needs = {o for name in comp for o in self.by_name[name].inputs} - set(comp)
                if needs <= done:
                    ordered.append(comp)
                    done.update(comp)
                    comps.remove(comp)
                    break
        return ordered

    @property
    def cycles(self) -> list[tuple[str, ...]]:
        return [c for c in self.components if len(c) > 1]

    def method_for(self, comp) -> str:
        """How a cycle is solved: the settings' method; ``auto`` is monolithic when every block
        of the cycle has a residual form, partitioned otherwise."""
        if self.settings.method != "auto":
            return self.settings.method
        return "monolithic" if all(self.by_name[n].has_residual for n in comp) else "partitioned"

    def relaxed_field(self, comp: tuple[str, ...]) -> str:
        """The field a partitioned sweep over ``comp`` relaxes (and measures convergence on)."""
        return self.settings.relax if self.settings.relax in comp else comp[-1]

    def with_blocks(self, *extra: FieldBlock) -> "BlockSystem":
        """The same system with more blocks."""
        return BlockSystem(self.blocks + tuple(extra), self.settings, self.linear_algebra)

    def split(self, z: np.ndarray, names=None) -> dict[str, np.ndarray]:
        """A stacked vector (in the order of ``names``) as fields."""
        names = self.names if names is None else names
        out, start = {}, 0
        for name in names:
            size = self.by_name[name].size
            out[name] = z[start:start + size]
            start += size
        return out

    def jacobian(self, lins: dict[str, Linearization], names, kept: dict | None = None) -> sp.csr_matrix:
        """The block Jacobian ``[[dR_a/dz_b]]`` of the fields ``names`` from their linearizations
        (``kept``: couplings ``(a, b) -> matrix`` to use instead, quasi-Newton)."""
        kept = kept or {}
        rows = []
        for a in names:
            lin = lins[a]
            blocks = [lin.matrix() if b == a else kept[(a, b)] if (a, b) in kept else
                      (lin.coupling(b) if b in self.by_name[a].inputs else None) for b in names]
            rows.append(sp.hstack([canonical_csr(B) if B is not None else      # CSR fast paths:
                                   sp.csr_matrix((self.by_name[a].size, self.by_name[b].size))
                                   for B, b in zip(blocks, names, strict=True)], format="csr"))
        return sp.vstack(rows, format="csr")                    # no COO round trip, unlike bmat

    def block_jacobian(self, lins: dict[str, Linearization], names, kept: dict | None = None,
                       at=None) -> BlockMatrix:
        """The block Jacobian of :meth:`jacobian` kept as its blocks (products, a block
        preconditioner's diagonal blocks), assembled by nobody unless a whole-matrix LU asks
        (a coupling known by its products only stays a :class:`~tofsi.linalg.LinearMap`);
        ``at``: the point ``lins`` were taken at (:class:`~tofsi.coupling.jacobian_point.JacobianPoint`,
        the matrix's ``origin``)."""
        kept = kept or {}
        blocks = {}
        for i, a in enumerate(names):
            lin = lins[a]
            for j, b in enumerate(names):
                B = (lin.matrix() if b == a else kept[(a, b)] if (a, b) in kept else
                     (lin.coupling(b) if b in self.by_name[a].inputs else None))
                if B is not None:
                    blocks[(i, j)] = B if sp.isspmatrix_csr(B) or isinstance(B, LinearMap) else sp.csr_matrix(B)
        return BlockMatrix(blocks, [self.by_name[n].size for n in names], origin=at)

    def ordering(self, names) -> np.ndarray | None:
        """Nested-dissection permutation of the stacked unknowns of ``names`` (None: unknown grid);
        computed once per tuple of names (the blocks' grids never change). One block's is its
        physics' own where it keeps one (:meth:`FieldBlock.ordering`: the same permutation, made
        once for both; 0.15 s at 160 x 80 for the flow, the structure and the mesh)."""
        names = tuple(names)
        if names not in self._orderings:
            own = self.by_name[names[0]].ordering() if len(names) == 1 else None
            self._orderings[names] = own if own is not None else self._nested_dissection(names)
        return self._orderings[names]

    def _nested_dissection(self, names) -> np.ndarray | None:
        grids = [self.by_name[n].ordering_grid() for n in names]
        if any(g is None for g in grids):
            return None
        coords = np.vstack([g[0] for g in grids])
        last = np.concatenate([g[1] for g in grids])
        return nested_dissection(coords, last=last)

    def linear_solver(self, comp, kind: str | None = None) -> RecyclingSolver:
        """The Newton's linear solver of the cycle ``comp`` (``kind``: else the settings'
        ``jacobian_solver``): ``block``, GMRES preconditioned by block Gauss-Seidel over the
        fields' own factorizations (:class:`~tofsi.linalg.BlockGaussSeidel`), kept for the
        later iterates and the adjoint while it stays cheap; ``direct``, the LU of the whole
        Jacobian, whose factors precondition GMRES for the later iterates and the adjoint."""
        kind = kind or self.settings.jacobian_solver
        direct = self.linear_algebra.direct
        if kind == "direct":
            perm = self.ordering(comp)
            return RecyclingSolver(lambda A: direct(A.tocsr() if isinstance(A, BlockMatrix) else A, perm=perm))
        orderings = [self.ordering((n,)) for n in comp]
        return RecyclingSolver(lambda A: BlockGaussSeidel(A, orderings=orderings, direct=direct))

    # ---- forward solve ------------------------------------------------------------------
    def solve(self, rho: np.ndarray, params: Continuation, guess: State | None = None,
              progress=None, direct: bool = False, tol: float | None = None, load_step: bool = False,
              factors: dict | None = None) -> State:
        """Every field for densities ``rho``; ``guess`` (a state) warm-starts the solvers;
        ``direct``: the blocks' own solves without their own continuation (``FieldBlock.solve``),
        for a caller that continues along a path of its own when this fails; ``tol``: the
        cycles' tolerance instead of the settings' (a continuation's step short of its end);
        ``load_step``: a step of the inflow ramp (:func:`~tofsi.coupling.monolithic.solve_monolithic`;
        its Newton starts from the solver of the guess's cycle, the last step's, where it has one);
        ``factors``: else a cycle's solver to start from (by the cycle's names: the previous
        design's, :mod:`tofsi.optimization.carried_factors`)."""
        fields = {name: None for name in self.names}
        if guess is not None:
            for name in self.names:
                if guess.fields.get(name) is not None:
                    fields[name] = np.array(guess.fields[name], dtype=float)
        state = State(rho=rho, params=params)
        for comp in self.components:
            if len(comp) == 1:
                fields[comp[0]] = self._solve_block(comp[0], fields, state, progress, direct=direct)
            elif self.method_for(comp) == "monolithic":
                last = guess.coupled.get(comp) if load_step and guess is not None else None
                solve_monolithic(self, comp, fields, state, direct, tol, load_step,
                                 recycled=(factors or {}).get(comp) if last is None else last.solver)
            else:
                self._partitioned(comp, fields, state, progress, direct, tol)
        state.fields = fields
        state.converged = True
        return state

    def _solve_block(self, name, fields, state, progress=None, previous=None, direct=False, tol=None):
        block = self.by_name[name]
        value, lin, report = block.solve(fields, state.rho, state.params, guess=fields.get(name),
                                         previous=previous, progress=progress,
                                         **({"direct": True} if direct and block.own_continuation else {}),
                                         **({"tol": tol} if tol is not None and block.takes_tolerance else {}))
        state.linearizations[name] = lin
        if report is not None and block.report_name:
            state.reports[block.report_name] = report
        return value

    def start(self, comp, fields, state, progress=None, direct=False, tol=None) -> None:
        """Fill the fields of the cycle ``comp`` that have no guess: one sweep in order (each block
        solved with the latest values of the others, absent ones at their initial value;
        ``direct``: without the blocks' own continuation; ``tol``: each block that takes one
        solved to that scaled residual only, ``FieldBlock.takes_tolerance``). A block's failure
        leaves the fields solved before it on the error (``solved``: a failed direct attempt's flow
        starts the inflow ramp, :mod:`tofsi.coupling.load_ramp`)."""
        if all(fields[n] is not None for n in comp):
            return
        for name in comp:
            if fields[name] is None:
                fields[name] = self.by_name[name].initial(fields, state.rho, state.params)
        solved = {}
        for name in comp:
            try:
                fields[name] = self._solve_block(name, fields, state, progress, direct=direct, tol=tol)
            except NumericalError as err:
                err.solved = solved         # the fields this sweep solved before it failed
                raise
            solved[name] = fields[name]

    def _partitioned(self, comp, fields, state, progress, direct=False, tol=None) -> None:
        s = self.settings
        tol = s.tol if tol is None else tol
        relax = self.relaxed_field(comp)
        for name in comp:
            if fields[name] is None:
                fields[name] = self.by_name[name].initial(fields, state.rho, state.params)
        accelerator, history = InterfaceQuasiNewton(s.relaxation), []
        at = comp.index(relax)
        for k in range(s.max_iter):
            for name in comp[:at]:
                fields[name] = self._solve_block(name, fields, state, progress,
                                                 state.linearizations.get(name), direct)
            new = self._solve_block(relax, fields, state, progress, state.linearizations.get(relax), direct)
            change = float(np.linalg.norm(new - fields[relax]) / max(np.linalg.norm(new), 1e-300))
            history.append({"iteration": k, "relative_change": change})
            log.info("partitioned coupling %d: relative change of %s %.3e", k, relax, change)
            converged = change <= tol
            fields[relax] = new if converged else accelerator.next(fields[relax], new)
            for name in comp[at + 1:]:
                fields[name] = self._solve_block(name, fields, state, progress,
                                                 state.linearizations.get(name), direct)
            if converged:
                for name in comp[:at]:              # consistent with the final later fields
                    fields[name] = self._solve_block(name, fields, state, progress,
                                                     state.linearizations.get(name), direct)
                state.reports["coupling"] = {"method": "partitioned", "history": history}
                return
        raise NumericalError(f"partitioned coupling did not converge in {s.max_iter} iterations",
                             {"history": history})
