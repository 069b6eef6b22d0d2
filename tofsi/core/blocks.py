"""The block protocol: one interface for every field of a coupled problem.

A coupled problem is a set of fields ``z_b`` (the flow ``w``, the structure
``u``, the mesh motion ``x``, or a field of your own), each with a residual

    R_b(z_b; z_inputs, rho, params) = 0,

written in the *constrained* form: free rows the physics, fixed (Dirichlet)
rows ``z_b - g_b`` with ``g_b`` the prescribed values (which may depend on
the inputs, e.g. a mesh node that follows the structure). A
:class:`FieldBlock` knows its own residual, how to solve it given its
inputs, and how to linearize it; a :class:`Linearization` is the block's
derivatives at one point and owns the factorization of its own Jacobian:

* ``matrix()`` ``dR_b/dz_b`` (sparse), identity on the fixed rows (the free
  rows' fixed columns may be dropped where the prescribed values are
  constants: no Newton step or adjoint moves them);
* ``solve(b)`` / ``solve_transpose(b)`` with that matrix (the adjoint reuses
  the forward factorization);
* ``coupling(other)`` ``dR_b/dz_other`` (sparse; needed by monolithic Newton);
* ``transpose_partials(lam)`` ``({other: (dR_b/dz_other)^T lam}, (dR_b/drho)^T lam)``
  -- all the adjoint needs.

A block whose map has no residual form (a mesh mover solved in increments
on the updated mesh) is written as the explicit map ``R = z - Phi(inputs)``:
its linearization has ``matrix() = I`` and ``transpose_partials`` is minus the
map's vector-Jacobian product (:class:`ExplicitLinearization`); with the
map's tangent its couplings ``-Phi_other`` are operators (products only,
``FieldBlock.matrix_free_couplings``), and monolithic Newton solves it too.

Continuation parameters (SIMP penalty, Brinkman q, projection sharpness,
load exponent) are inputs of every solve, a frozen :class:`Continuation`
record; no physics object is ever changed to switch them.
:class:`tofsi.coupling.block_system.BlockSystem` orders the blocks and solves them;
:mod:`adjoint` differentiates any system of blocks without naming a physics.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping

import numpy as np
import scipy.sparse as sp

Fields = Mapping[str, np.ndarray]


@dataclass(frozen=True)
class Continuation:
    """Continuation parameters of one solve: the numbers a residual reads.

    penalty : SIMP exponent ``p`` of ``E(rho) = Emin + rho^p (E0 - Emin)``
    brinkman_q : convexity ``q`` of the Brinkman interpolation ``alpha(rho)``
    beta : projection sharpness of the design map (recorded with the state)
    load_exponent : weight ``rho^k`` of the solid phase in the fluid load
    load : the fraction of the flow's prescribed boundary velocities (the inflow) the
        solve applies: 1 is the problem; below 1, a step of the load continuation that
        carries a coupled solve to large motion (:mod:`tofsi.coupling.load_ramp`)
    """

    penalty: float = 3.0
    brinkman_q: float = 0.1
    beta: float = 0.0
    load_exponent: float = 1.0
    load: float = 1.0


@dataclass(frozen=True)
class Stage:
    """A continuation stage: the numbers its residuals read and its structure, which the model
    reads to choose the blocks (residuals never see it).

    params : the :class:`Continuation` numbers of the stage's solves
    coupling : ``"one-way"`` to solve a two-way problem one-way (a stage of a design schedule),
        ``"two-way"``, or ``""``: as the problem is
    material : the structure's material this stage (a registry name, e.g. ``"linear"`` while
        the design is gray, ``"neo-hookean"`` once the topology exists); ``""``: the scene's
        ``structure.model``
    """

    params: Continuation = field(default_factory=Continuation)
    coupling: str = ""
    material: str = ""

    def with_params(self, **numbers) -> "Stage":
        """The same stage with some numbers replaced (``stage.with_params(beta=16.0)``)."""
        return replace(self, params=replace(self.params, **numbers))


class Linearization(ABC):
    """A block's derivatives at one point ``(fields, rho, params)``.

    Subclasses build what they are asked for on first use and keep it: an
    instance belongs to one point, so nothing it caches can go stale.
    """

    def __init__(self, block: "FieldBlock", fields: Fields, rho, params: Continuation):
        self.block, self.rho, self.params = block, rho, params
        self.fields = {k: (None if v is None else np.array(v, dtype=float)) for k, v in fields.items()}
        self._kept: dict = {}

    def kept(self, key, build: Callable):
        """``build()`` once per ``key`` (a linearization belongs to one point: nothing goes stale)."""
        if key not in self._kept:
            self._kept[key] = build()
        return self._kept[key]

    @property
    def value(self) -> np.ndarray:
        """The block's own field at the point."""
        return self.fields[self.block.name]

    @property
    def residual(self) -> np.ndarray:
        """The block's constrained residual at the point (monolithic Newton reads it)."""
        return self.block.residual(self.fields, self.rho, self.params)

    @abstractmethod
    def matrix(self) -> sp.spmatrix:
        """``dR/dz`` of the block's own field, identity on the fixed rows."""

    @abstractmethod
    def solve(self, b: np.ndarray) -> np.ndarray:
        """``matrix()^-1 b``."""

    @abstractmethod
    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        """``matrix()^-T b`` (the adjoint solve, with the forward factorization)."""

    def coupling(self, other: str) -> sp.spmatrix:
        """``dR/dz_other`` as a sparse matrix (monolithic Newton), or an operator with products
        ``@`` and ``.T @`` where the block lists ``other`` in ``matrix_free_couplings``; ``None``
        if it is zero."""
        raise NotImplementedError(f"block {self.block.name!r} gives no coupling matrix; "
                                  "it cannot take part in a monolithic solve")

    def density(self) -> sp.spmatrix | None:
        """``dR/drho`` (size x E) as a sparse matrix, or None if the residual does not depend on rho."""
        return None

    def transpose_partials(self, lam: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
        """``({other: (dR/dz_other)^T lam}, (dR/drho)^T lam)`` for the inputs and the densities."""
        bars = {}
        for other in self.block.inputs:
            C = self.coupling(other)
            if C is not None:
                bars[other] = C.T @ lam
        D = self.density()
        return bars, (None if D is None else D.T @ lam)


class ExplicitLinearization(Linearization):
    """The linearization of an explicit map ``z = Phi(inputs, rho)``, written as ``R = z - Phi``.

    vjp : ``zbar -> ({input: Phi_input^T zbar}, Phi_rho^T zbar)``
    """

    def __init__(self, block, fields, rho, params, vjp: Callable):
        super().__init__(block, fields, rho, params)
        self.vjp = vjp

    def matrix(self) -> sp.spmatrix:
        return sp.identity(self.block.size, format="csr")

    def solve(self, b: np.ndarray) -> np.ndarray:
        return np.array(b, dtype=float)

    def solve_transpose(self, b: np.ndarray) -> np.ndarray:
        return np.array(b, dtype=float)

    def transpose_partials(self, lam):
        bars, rho_bar = self.vjp(np.asarray(lam, dtype=float))
        return ({k: -v for k, v in bars.items()}, None if rho_bar is None else -rho_bar)


class FieldBlock(ABC):
    """One field of a coupled problem: its residual, its solve and its linearization.

    Attributes a block sets: ``name`` (the field's name, e.g. ``"u"``), ``size``
    (number of unknowns), ``inputs`` (names of the other fields the residual
    depends on), ``symbol`` and ``report_name`` (how reports call it) and
    ``fixed`` (the indices of its Dirichlet dofs: the boundary operator,
    applied homogeneously by every Newton step and adjoint solve).
    """

    name: str
    size: int
    inputs: tuple[str, ...] = ()
    symbol: str = ""                   # the residual's letter in reports (F, S, D); default the name
    report_name: str = ""
    has_residual: bool = True          # False: an explicit map without a residual form
    slow_couplings: tuple[str, ...] = ()   # couplings a quasi-Newton solve may keep fixed
    matrix_free_couplings: tuple[str, ...] = ()   # couplings known by their products only (no LU of the whole)
    own_continuation: bool = False     # solve() continues in a load of its own, and takes ``direct`` to skip it
    takes_tolerance: bool = False      # solve() takes ``tol``: the scaled residual to stop at (a sweep's start)

    @property
    @abstractmethod
    def fixed(self) -> np.ndarray:
        """Indices of the Dirichlet dofs."""

    def homogenize(self, r: np.ndarray) -> np.ndarray:
        """``r`` with the Dirichlet entries set to zero (the homogeneous boundary operator)."""
        r = np.array(r, dtype=float, copy=True)
        r[self.fixed] = 0.0
        return r

    @abstractmethod
    def initial(self, fields: Fields, rho, params: Continuation) -> np.ndarray:
        """A starting value (prescribed values in place)."""

    def residual(self, fields: Fields, rho, params: Continuation) -> np.ndarray:
        """``R`` in the constrained form (fixed rows ``z - g``)."""
        raise NotImplementedError(f"block {self.name!r} has no residual form")

    def linearize(self, fields: Fields, rho, params: Continuation) -> Linearization:
        """The block's derivatives at ``fields`` (for monolithic Newton and checks)."""
        raise NotImplementedError(f"block {self.name!r} has no residual form")

    @abstractmethod
    def solve(self, fields: Fields, rho, params: Continuation, guess: np.ndarray | None = None,
              previous: Linearization | None = None, progress=None):
        """``(z, linearization, report)`` with ``R(z; fields) = 0``.

        guess : a starting value; previous : this block's linearization from an
        earlier solve of the same coupled solve (its factorization may be
        reused as a preconditioner); report : a JSON-friendly dict. A block with
        ``own_continuation`` (its solve steps a load of its own when Newton fails: a
        finite-strain structure) also takes ``direct=True`` from a caller that carries the
        coupled problem along a path of its own when this solve fails (the inflow ramp after
        a direct attempt from a one-way state): no continuation of its own, fail fast. A block
        with ``takes_tolerance`` also takes ``tol``: the largest residual relative to its force
        scale (:meth:`residual_scale`) to stop at instead of its own tolerance, for a sweep that
        only starts a coupled Newton.
        """

    def residual_scale(self, fields: Fields, rho, params: Continuation, lin: Linearization) -> float:
        """A force scale that ``|R|`` is measured against by monolithic Newton."""
        return max(float(np.linalg.norm(lin.matrix() @ lin.value)), 1e-300)

    def ordering_grid(self):
        """``(coords (size, 2) int, last (size,) bool)`` fine-grid positions of the dofs for
        the nested-dissection ordering of monolithic systems, or None."""
        return None

    def ordering(self):
        """The fill-reducing permutation of this block's unknowns alone that its physics keeps
        (the one its own solves factorize with), or None: the block system makes one from
        :meth:`ordering_grid`."""
        return None


@dataclass
class State:
    """A solved coupled state: the fields (absent ones are None) and what produced them.

    linearizations : each block's linearization at the state (the adjoint's input)
    coupled : the monolithic Newton's linearization of each cycle it solved, by its fields
    """

    rho: np.ndarray
    fields: dict = field(default_factory=dict)
    params: Continuation = field(default_factory=Continuation)
    converged: bool = False
    reports: dict = field(default_factory=dict)
    linearizations: dict = field(default_factory=dict)
    coupled: dict = field(default_factory=dict)
    stage: Stage = field(default_factory=Stage)     # the stage the model solved it at (its blocks)

    @property
    def w(self) -> np.ndarray | None:
        """Flow unknowns (velocity, pressure)."""
        return self.fields.get("w")

    @property
    def u(self) -> np.ndarray | None:
        """Structural displacement (2n,) [m]."""
        return self.fields.get("u")

    @property
    def x(self) -> np.ndarray | None:
        """Fluid-mesh displacement (2n,) [m]."""
        return self.fields.get("x")

    @property
    def mesh_displacement(self) -> np.ndarray | None:
        """Fluid-mesh displacement ``(n, 2)`` the flow was solved on (None: reference mesh)."""
        return None if self.x is None else self.x.reshape(-1, 2)

    def data(self) -> "State":
        """The same state without linearizations (no factorizations held: for records)."""
        return State(self.rho, dict(self.fields), self.params, self.converged, self.reports, stage=self.stage)
