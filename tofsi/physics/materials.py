"""The structure's materials, entries of :data:`tofsi.core.registry.MATERIALS`.

A material is chosen once -- by ``structure.model``, or per continuation stage by
``design.structure_model`` -- and is then an object that the structure and its
block ask, never a name compared again. It gives, at densities ``rho`` with the
SIMP modulus interpolation ``simp`` (:class:`~tofsi.physics.interpolation.SIMP`):

* ``internal_forces(u, rho, simp)`` -- ``R_int(u; rho)`` (2n,) [N/m], reactions included;
* ``tangent(u, rho, simp)`` -- ``dR_int/du`` constrained (identity on the clamped dofs);
* ``density_vectors(u, rho, simp)`` -- ``dR_int,e/drho_e`` ``(E, 8)``;
* ``solver(rho, simp, previous)`` -- the solver of its tangent's systems at a point
  (``solve(tangent, b)``, ``solve_transpose(tangent, b)``, ``tangent()`` giving the point's
  tangent where the solver needs it): ``previous``, an earlier one of the same coupled
  solve, where it still serves;
* ``solve(f, rho, simp, guess, solver)`` -- ``(u, report)`` with ``R_int(u) = f`` on the
  free dofs (``report``: a JSON-friendly dict, or None);
* ``nonlinear`` -- whether ``R_int`` is nonlinear in ``u`` (its tangent depends on ``u``).

A material of your own is one class registered with ``@MATERIALS.register``
(a finite-strain one: a subclass of :class:`FiniteStrain` with its element
``kernel``, which the Newton solve, the load steps and the adjoint then use).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tofsi.core.registry import MATERIALS
from tofsi.fem.assembly import assemble_vector
from tofsi.fem.neo_hookean import NeoHookeanKernel
from tofsi.fem.saint_venant_kirchhoff import SaintVenantKirchhoffKernel
from tofsi.linalg import RecyclingSolver
from tofsi.physics.finite_strain import FiniteStrainElasticity
from tofsi.physics.interpolation import SIMP


class Material:
    """A structure material bound to one :class:`~tofsi.physics.structure.Structure` (its mesh,
    clamped dofs, settings and linear algebra): see the module docstring.

    name : the value of ``structure.model`` that chooses it; nonlinear : ``R_int`` nonlinear in ``u``.
    """

    name: str
    nonlinear: bool

    def __init__(self, structure):
        self.structure = structure

    def internal_forces(self, u, rho, simp: SIMP) -> np.ndarray:
        raise NotImplementedError

    def tangent(self, u, rho, simp: SIMP) -> sp.csr_matrix:
        raise NotImplementedError

    def density_vectors(self, u, rho, simp: SIMP) -> np.ndarray:
        raise NotImplementedError

    def solver(self, rho, simp: SIMP, previous=None):
        raise NotImplementedError

    def solve(self, f, rho, simp: SIMP, guess=None, solver=None, direct=False,
              tol=None) -> tuple[np.ndarray, dict | None]:
        """``(u, report)`` with ``R_int(u) = f``; ``direct``: from the guess without the material's
        own continuation (a nonlinear one's load steps), failing fast; ``tol``: a nonlinear one's
        Newton tolerance relative to the load instead of its own (a linear one solves exactly)."""
        raise NotImplementedError


class StiffnessSolver:
    """Small strain: the factorization of ``K_s(rho)`` at one SIMP interpolation (the LU, or AMG on
    the iterative path), made on first use; it solves every system with that matrix, so a
    coupled solve's sweeps reuse it while ``rho`` and the interpolation stay."""

    def __init__(self, material: "SmallStrain", rho, simp: SIMP):
        self.material, self.simp = material, simp
        self.rho = np.array(rho, dtype=float)
        self._factor = None

    def serves(self, rho, simp: SIMP) -> bool:
        """Whether the factorization is that of ``K_s`` at ``rho`` and ``simp``."""
        return self.simp == simp and np.array_equal(self.rho, rho)

    @property
    def factor(self):
        if self._factor is None:
            K = self.material.tangent(None, self.rho, self.simp)
            self._factor = self.material.structure.linear_solver(K)
        return self._factor

    def solve(self, tangent, b: np.ndarray) -> np.ndarray:
        """``K_s^-1 b`` (``tangent()`` is ``K_s`` itself: not needed)."""
        return self.factor.solve(b)

    def solve_transpose(self, tangent, b: np.ndarray) -> np.ndarray:
        return self.factor.solve_transpose(b)


class TangentSolver:
    """Finite strain: a point's tangent systems solved by the Newton's recycling solver (its last
    factorization preconditions GMRES on the tangent)."""

    def __init__(self, recycling: RecyclingSolver):
        self.recycling = recycling

    def solve(self, tangent, b: np.ndarray) -> np.ndarray:
        return self.recycling.solve(tangent(), b)

    def solve_transpose(self, tangent, b: np.ndarray) -> np.ndarray:
        return self.recycling.solve_transpose(tangent(), b)


@MATERIALS.register
class SmallStrain(Material):
    """Small-strain plane-strain elasticity: ``R_int = K_s(rho) u``, ``K_s = sum_e E(rho_e) K0_e``."""

    name, nonlinear = "linear", False

    def element_forces(self, u, moduli) -> np.ndarray:
        st = self.structure
        return np.einsum("eab,eb->ea", st.K0, np.asarray(u)[st.dofs]) * moduli[:, None]

    def internal_forces(self, u, rho, simp):
        st = self.structure
        return assemble_vector(st.dofs, self.element_forces(u, simp(rho)), st.size)

    def tangent(self, u, rho, simp):
        st = self.structure
        return st.bc.matrix(st.K0 * simp(rho)[:, None, None])

    def density_vectors(self, u, rho, simp):
        return self.element_forces(u, simp.derivative(rho))

    def solver(self, rho, simp, previous=None) -> StiffnessSolver:
        if isinstance(previous, StiffnessSolver) and previous.material is self and previous.serves(rho, simp):
            return previous                                   # K_s depends on (rho, p) only
        return StiffnessSolver(self, rho, simp)

    def solve(self, f, rho, simp, guess=None, solver=None, direct=False, tol=None):
        solver = self.solver(rho, simp) if solver is None else solver
        return solver.solve(None, self.structure.bc.homogenize(f)), None


@MATERIALS.register
class FiniteStrain(Material):
    """Compressible neo-Hookean finite strain (plane strain, total Lagrangian), nearly void elements
    by ``structure.interpolation`` (:mod:`tofsi.physics.finite_strain`); Newton with load steps,
    cutback and line search, its linear solves by a recycling solver (the LU preconditions the
    later tangents)."""

    name, nonlinear = "neo-hookean", True
    kernel = NeoHookeanKernel                 # the element kernel (a subclass: another hyperelastic law)

    def __init__(self, structure):
        super().__init__(structure)
        st = structure
        self.elasticity = FiniteStrainElasticity(st.mesh, st.settings, st.bc, st.dofs, st.direct, st.K0,
                                                 kernel=self.kernel)

    def internal_forces(self, u, rho, simp):
        return self.elasticity.internal_forces(u, rho, simp)

    def tangent(self, u, rho, simp):
        return self.elasticity.tangent(u, rho, simp)

    def density_vectors(self, u, rho, simp):
        return self.elasticity.density_vectors(u, rho, simp)

    def solver(self, rho, simp, previous=None) -> TangentSolver:
        if isinstance(previous, TangentSolver):
            return previous
        return TangentSolver(RecyclingSolver(self.structure.direct))

    def solve(self, f, rho, simp, guess=None, solver=None, direct=False, tol=None):
        solver = self.solver(rho, simp) if solver is None else solver
        solution = self.elasticity.solve(f, rho, simp, guess, solver.recycling, load_steps=not direct, tol=tol)
        return solution.u, solution.report.as_dict()


@MATERIALS.register
class SaintVenantKirchhoff(FiniteStrain):
    """Saint Venant-Kirchhoff finite strain, ``W = lam/2 (tr E)^2 + mu E:E`` in the Green-Lagrange
    strain ``E`` (Turek & Hron's solid; :mod:`tofsi.fem.saint_venant_kirchhoff`): the neo-Hookean
    material's Newton, load steps, void treatment and adjoint with another element kernel."""

    name = "saint-venant-kirchhoff"
    kernel = SaintVenantKirchhoffKernel
