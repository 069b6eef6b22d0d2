"""Finite-strain elasticity of the unified domain: forces, tangent, Newton solve.

Total Lagrangian on the reference mesh, plane strain, element kernel
a :class:`~tofsi.fem.hyperelastic.HyperelasticKernel` of the material
(:class:`~tofsi.fem.neo_hookean.NeoHookeanKernel` by default,
:class:`~tofsi.fem.saint_venant_kirchhoff.SaintVenantKirchhoffKernel`). Element moduli by SIMP,
``E_e = Emin + rho_e^p (E0 - Emin)``; nearly void elements by the energy
interpolation of Wang et al. (2014): ``W_e = E_e [W_NL(g u) - W_L(g u) + W_L(u)]``
with ``g = g(rho)`` (:class:`~tofsi.fem.hyperelastic.NonlinearWeight`), or plain
SIMP (``g = 1``: every element nonlinear). The residual is

    S(u; w, x, rho) = R_int(u; rho) - f(w, x, rho),

with the fluid load ``f`` fixed during the structure's own solve (it moves with
the fluid mesh ``x``, a separate field in two-way coupling: the follower
load's dependence on the motion is the coupling block ``S_x``).

:meth:`FiniteStrainElasticity.solve`: Newton-Raphson with inexact
(Eisenstat-Walker, at most ``FORCING_CAP``) linear solves by a
:class:`~tofsi.linalg.RecyclingSolver` (the first factorization
preconditions GMRES on the later tangents) and a backtracking line search on
the potential ``Pi = sum_e W_e(u) - f . u`` (the residual is its gradient)
that rejects steps inverting an element (``det F <= 0`` in the nonlinear
part). From its start -- zero, or a ``guess`` (the previous design's,
coupling sweep's or inflow step's displacement) -- Newton goes to the full
load; when that fails the load is stepped from the start's own load (zero,
or ``R_int(guess)``) to ``f``, a failed step halved (cutback), an easy one
followed by a longer one. The first Newton step from zero is the linear
solution (the tangent at ``u = 0`` is the small-strain stiffness). Failure
raises :class:`~tofsi.core.errors.NumericalError` with the worst element
(smallest ``det F``, its centroid).
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.sparse as sp

from tofsi.core.errors import NumericalError
from tofsi.fem.assembly import assemble_vector
from tofsi.fem.hyperelastic import ElementValues, HyperelasticKernel, NonlinearWeight
from tofsi.fem.neo_hookean import NeoHookeanKernel
from tofsi.physics.interpolation import SIMP
from tofsi.core.iteration import forcing_term
from tofsi.core.kept import Kept, input_key
from tofsi.linalg import RecyclingSolver

log = logging.getLogger(__name__)
ROUND_OFF = 1e3 * np.finfo(float).eps      # attainable |S| relative to the internal forces' size
# Largest relative tolerance of a Newton step's linear solve: |S| mixes the stiff solid's rows with
# the void's (contrast E0 / Emin), so a step solved to 10 % of |S| can leave the soft modes
# unresolved (a bending beam near a wall: 9 Newton iterations instead of 5 at 6 % deflection).
FORCING_CAP = 1e-2
# Elements whose blend g(rho) is at most this are evaluated as linear: W_NL(g u) - W_L(g u) is
# O(g^3 |grad u|^3), so their forces and tangents differ from the linear element's by
# O(g^3 |grad u|) relative (1e-18 for |grad u| = 1), and the void of a design (rho ~ 1e-6
# after projection, g ~ 5e-8) skips the kernel.
LINEAR_BELOW = 1e-6
# A Newton without load steps of its own (a coupled solve's direct attempt) fails when its residual has
# not halved in this many iterations: its caller's path is cheaper than the crawl (the large scene at
# 80 x 40: 5 iterations there, not 12 with 8; E = 2.5 kPa there halves it in 4 and goes on to converge).
STALL_ITERATIONS = 5


@dataclass
class FiniteStrainReport:
    converged: bool = False
    newton_iterations: int = 0
    load_steps: int = 0
    cutbacks: int = 0
    warm_start: bool = False
    factorizations: int = 0
    min_det_F: float = float("nan")           # smallest det F of the nonlinear part at the solution
    residual_history: list = field(default_factory=list)
    wall_time_s: float = 0.0

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class FiniteStrainSolution:
    """A converged displacement, its report and the solver holding the last factorization."""

    u: np.ndarray
    report: FiniteStrainReport
    solver: RecyclingSolver


class StepFailed(Exception):
    """A load step that did not converge (the caller cuts it back)."""

    def __init__(self, reason: str, u: np.ndarray):
        super().__init__(reason)
        self.u = u


class FiniteStrainElasticity:
    """A finite-strain structure's internal forces, tangent, density partials and Newton solve.

    mesh : the structured mesh (reference configuration); settings : the
    :class:`~tofsi.scene.settings.StructureSettings` (``poisson_ratio``,
    ``interpolation``, ``energy_threshold``, ``energy_sharpness``,
    ``newton_tol``, ``max_newton``, ``max_cutbacks``); bc : the clamped dofs'
    :class:`~tofsi.fem.dirichlet.DirichletOperator`; dofs : element dofs
    ``(E, 8)``; factorize : ``A -> `` a direct solver of the tangent ``A`` (the
    structure's backend and ordering); K0 : the small-strain element stiffness per
    unit modulus, if already made; kernel : the material's
    :class:`~tofsi.fem.hyperelastic.HyperelasticKernel` class.
    """

    def __init__(self, mesh, settings, bc, dofs, factorize, K0=None, kernel=NeoHookeanKernel):
        self.mesh, self.settings, self.bc, self.dofs = mesh, settings, bc, dofs
        self.factorize = factorize
        self.size = bc.size
        self.kernel_type = kernel
        self.kernel = kernel(mesh.points[mesh.quads], settings.poisson_ratio, K0)
        self.weight = (None if settings.interpolation == "simp"
                       else NonlinearWeight(settings.energy_threshold, settings.energy_sharpness))
        self._restricted = Kept()            # the kernel of the last set of nonlinear elements

    # ---- element values -------------------------------------------------------------------
    def nonlinear_weight(self, rho) -> tuple[np.ndarray, np.ndarray]:
        """``g(rho)`` and ``g'(rho)`` ``(E,)`` (ones and zeros for plain SIMP)."""
        rho = np.asarray(rho, dtype=float)
        if self.weight is None:
            return np.ones_like(rho), np.zeros_like(rho)
        return self.weight(rho), self.weight.derivative(rho)

    def nonlinear_elements(self, rho) -> np.ndarray:
        """The elements evaluated by the material's kernel: ``g(rho) > LINEAR_BELOW``."""
        return np.flatnonzero(self.nonlinear_weight(rho)[0] > LINEAR_BELOW)

    def _kernel_of(self, elements: np.ndarray) -> HyperelasticKernel:
        if elements.size == self.kernel.n_elements:
            return self.kernel
        quads = self.mesh.quads[elements]
        return self._restricted.get(input_key(elements), lambda: self.kernel_type(
            self.mesh.points[quads], self.settings.poisson_ratio, self.kernel.K0[elements]))

    def _values(self, u, rho, simp: SIMP, tangent: bool) -> ElementValues:
        """The elements' values: the material kernel's on the nonlinear elements, the linear
        element's (``E K0 u``, ``E K0``, ``det F = 1``) elsewhere."""
        g, _ = self.nonlinear_weight(rho)
        modulus = simp(rho)
        ue = np.asarray(u)[self.dofs]
        nl = self.nonlinear_elements(rho)
        if nl.size == g.size:
            return self.kernel.evaluate(ue, modulus, g, tangent)
        part = self._kernel_of(nl).evaluate(ue[nl], modulus[nl], g[nl], tangent)
        det_min = np.ones(g.size)
        det_min[nl] = part.det_min
        if part.forces is None:
            return ElementValues(None, None, det_min, None)
        K0u = self.kernel.linear_forces(ue)
        Re = modulus[:, None] * K0u
        We = 0.5 * modulus * np.einsum("ea,ea->e", ue, K0u)
        Re[nl], We[nl] = part.forces, part.energy
        Ke = None
        if tangent:
            Ke = modulus[:, None, None] * self.kernel.K0
            Ke[nl] = part.tangents
        return ElementValues(Re, Ke, det_min, We)

    def element_values(self, u, rho, simp: SIMP, tangent: bool = True):
        """Element internal forces ``(E, 8)``, tangents ``(E, 8, 8)`` (or None) and smallest
        ``det F`` ``(E,)``; raises :class:`~tofsi.core.errors.NumericalError` if an element inverts."""
        Re, Ke, det_min, _ = self._values(u, rho, simp, tangent)
        if Re is None:
            raise NumericalError("structure: an element is inverted (det F <= 0 in the nonlinear part)",
                                 self.worst_element(det_min))
        return Re, Ke, det_min

    def internal_forces(self, u, rho, simp: SIMP) -> np.ndarray:
        """``R_int(u; rho)`` (2n,) [N/m], reactions included."""
        return assemble_vector(self.dofs, self.element_values(u, rho, simp, tangent=False)[0], self.size)

    def tangent(self, u, rho, simp: SIMP) -> sp.csr_matrix:
        """``S_u = dR_int/du`` at ``u``, constrained (identity on the clamped dofs)."""
        return self.bc.matrix(self.element_values(u, rho, simp)[1])

    def density_vectors(self, u, rho, simp: SIMP) -> np.ndarray:
        """``dR_int,e/drho_e`` ``(E, 8)``: the ``E'(rho)`` and ``g'(rho)`` terms (``E'(rho) K0 u``
        on the linear elements)."""
        g, dg = self.nonlinear_weight(rho)
        ue = np.asarray(u)[self.dofs]
        dmodulus = simp.derivative(rho)
        vals = dmodulus[:, None] * self.kernel.linear_forces(ue)
        nl = self.nonlinear_elements(rho)
        if nl.size:
            vals[nl] = self._kernel_of(nl).density_vectors(ue[nl], simp(rho)[nl], dmodulus[nl], g[nl], dg[nl])
        if np.isnan(vals).any():
            raise NumericalError("structure: an element is inverted (det F <= 0 in the nonlinear part)",
                                 self.worst_element(self._values(u, rho, simp, False).det_min))
        return vals

    def energy(self, u, rho, simp: SIMP) -> float:
        """Strain energy ``sum_e W_e(u)`` [J/m] (NaN if an element inverts)."""
        values = self._values(u, rho, simp, False)
        return float("nan") if values.energy is None else float(values.energy.sum())

    def worst_element(self, det_min: np.ndarray) -> dict:
        """The element with the smallest ``det F`` (of the nonlinear part) and where it is."""
        e = int(np.argmin(det_min))
        return {"worst_element": e, "min_det_F": float(det_min[e]),
                "centroid": [float(c) for c in self.mesh.centroids[e]]}

    # ---- Newton solve ------------------------------------------------------------------------
    def solve(self, f: np.ndarray, rho, simp: SIMP, guess: np.ndarray | None = None,
              solver: RecyclingSolver | None = None, load_steps: bool = True,
              tol: float | None = None) -> FiniteStrainSolution:
        """``u`` with ``R_int(u) = f`` on the free dofs and the clamped dofs at zero.

        guess : a displacement of a nearby problem (the previous coupling sweep's, design's or
            load step's); Newton goes from it straight to ``f``, and when that fails the load
            is stepped from the guess's own, ``f_g = R_int(guess)``, to ``f``
            (``f_g + t (f - f_g)``, ``t`` from 0 to 1). Without a guess (or one that inverts
            an element) the load is stepped from zero.
        solver : a :class:`~tofsi.linalg.RecyclingSolver` whose factorization may
            precondition this solve's tangents (a new one by default).
        load_steps : False: Newton from the start alone, a :class:`~tofsi.core.errors.NumericalError`
            when it fails (a caller with a continuation of its own: the coupled solve's
            direct attempt, which the inflow ramp follows).
        tol : the Newton's tolerance relative to the load instead of ``newton_tol`` (a solve
            that only starts a coupled Newton).
        The result does not depend on either (to ``newton_tol``).
        """
        t0 = time.perf_counter()
        report = FiniteStrainReport()
        solver = RecyclingSolver(self.factorize) if solver is None else solver
        factorizations = solver.factorizations
        f = self.bc.homogenize(f)
        start, state = np.zeros(self.size), self._unloaded(rho, simp)
        if guess is not None and np.all(np.isfinite(guess)) and np.any(guess):
            u0 = self.bc.homogenize(np.asarray(guess, dtype=float))
            values = self._values(u0, rho, simp, True)
            if values.forces is not None:
                start, state = u0, values
                report.warm_start = True
        f0 = self.bc.homogenize(assemble_vector(self.dofs, state.forces, self.size))
        try:
            u, state = self._newton(start, state, f, 1.0, rho, simp, solver, report,
                                    patience=None if load_steps else STALL_ITERATIONS, tol=tol)
        except StepFailed as failed:
            if not load_steps:
                self._fail(failed, 0.0, report, rho, simp, "Newton to the full load without load steps")
            log.info("structure: Newton to the full load failed (%s); load steps from %s", failed,
                     "the guess" if report.warm_start else "zero")
            u, state = self._load_steps(f, f0, start, state, rho, simp, solver, report, tol)
        report.min_det_F = float(state.det_min.min())
        report.converged = True
        report.factorizations = solver.factorizations - factorizations
        report.wall_time_s = time.perf_counter() - t0
        return FiniteStrainSolution(u, report, solver)

    def _load_steps(self, f, f0, u, state, rho, simp, solver, report: FiniteStrainReport, tol=None):
        """The load ``f0 + t (f - f0)`` from ``t = 0`` (where ``u`` is in equilibrium) to 1: a step
        that fails is halved, one that converged in a few iterations is followed by a longer one."""
        s = self.settings
        load, step = 0.0, 0.5
        while load < 1.0 - 1e-14:
            step = min(step, 1.0 - load)
            try:
                t = load + step
                u_new, state_new = self._newton(u, state, f0 + t * (f - f0), t, rho, simp, solver, report,
                                                tol=tol)
            except StepFailed as failed:
                report.cutbacks += 1
                step *= 0.5
                log.info("structure: load step to %.4g failed (%s); cut to %.3g", load + 2 * step, failed, step)
                if report.cutbacks > s.max_cutbacks or step < 1e-6:
                    self._fail(failed, load, report, rho, simp)
                continue
            u, state, load = u_new, state_new, load + step
            report.load_steps += 1
            if len(report.residual_history[-1]) <= 4:
                step *= 2.0
        return u, state

    def _unloaded(self, rho, simp) -> ElementValues:
        """The element values at ``u = 0``: no force, no energy, the small-strain stiffness
        (``K_NL(0) = K0``, so ``K_e = E_e K0_e`` for any ``g``)."""
        E = self.kernel.n_elements
        return ElementValues(np.zeros((E, 8)), simp(rho)[:, None, None] * self.kernel.K0, np.ones(E), np.zeros(E))

    def _fail(self, failed: StepFailed, load: float, report: FiniteStrainReport, rho, simp, how: str = ""):
        worst = self.worst_element(self._values(failed.u, rho, simp, False).det_min)
        origin = "the guess's load" if report.warm_start else "zero"
        how = how or f"no convergence at load factor {load:.4g} (from {origin}) after {report.cutbacks} cutbacks"
        raise NumericalError(
            f"structure ({self.kernel_type.material}): {how} ({failed}); smallest det F {worst['min_det_F']:.3g} in element "
            f"{worst['worst_element']} at ({worst['centroid'][0]:.3g}, {worst['centroid'][1]:.3g}) m",
            {**worst, "load_factor": load, "from_guess": report.warm_start, "cutbacks": report.cutbacks,
             "reason": str(failed), "newton_iterations": report.newton_iterations,
             "residual_history": report.residual_history[-3:]}, state=failed.u)

    def _newton(self, u, state, target_f, load: float, rho, simp, solver, report: FiniteStrainReport,
                patience: int | None = None, tol: float | None = None):
        """Newton to the load ``target_f`` (the step's ``load`` factor, for the log) from ``u`` and its
        element values ``state``; returns ``(u, state)`` or raises :class:`StepFailed` with the
        last iterate. With ``patience`` (a Newton without load steps of its own, whose caller
        continues along a path when it fails) it also stops when the residual has not halved in
        ``patience`` iterations: the large scene's direct attempt at 80 x 40 crawled from 9.9 to 2.5
        in 25 iterations before failing. ``tol`` replaces ``newton_tol``."""
        s = self.settings
        history: list[float] = []
        report.residual_history.append(history)
        scale = float(np.linalg.norm(target_f))
        for it in range(s.max_newton + 1):
            forces = assemble_vector(self.dofs, state.forces, self.size)
            r = self.bc.homogenize(forces - target_f)
            norm = float(np.linalg.norm(r))
            history.append(norm)
            target = max((s.newton_tol if tol is None else tol) * scale, ROUND_OFF * np.sqrt(self.size) * float(np.linalg.norm(forces)))
            log.info("structure Newton %d (load %.4g): |S| = %.3e, target %.3e", it, load, norm, target)
            if not np.isfinite(norm):
                raise StepFailed("non-finite residual", u)
            if norm <= target or norm == 0.0:
                return u, state
            if it == s.max_newton:
                raise StepFailed(f"{s.max_newton} Newton iterations", u)
            if patience and it >= patience and min(history[-patience:]) > 0.5 * history[-patience - 1]:
                raise StepFailed(f"the residual did not halve in {patience} Newton iterations", u)
            du = solver.solve(self.bc.matrix(state.tangents), -r,
                              rtol=min(FORCING_CAP, forcing_term(history, target)))
            du[self.bc.fixed] = 0.0
            report.newton_iterations += 1
            energy = float(state.energy.sum() - target_f @ u)
            u, state = self._line_search(u, du, energy, float(du @ r), norm, target_f, rho, simp)
        raise StepFailed("unreachable", u)

    def _line_search(self, u, du, energy0: float, slope0: float, norm0: float, target_f, rho, simp):
        """Step length along ``du`` on the potential ``Pi = sum_e W_e - f . u`` (the residual is its
        gradient): accept ``alpha`` when ``Pi`` decreases by ``1e-4 alpha`` of the slope
        ``slope0 = du . S`` (Armijo) or ``|S_free|`` decreases (round-off of ``Pi`` near the
        solution); otherwise the minimizer of the quadratic through ``Pi(0)``, ``slope0`` and
        ``Pi(alpha)``, kept in ``[alpha / 10, alpha / 2]``. A trial that inverts an element is
        halved. The full step's tangent is the next iteration's. Returns ``(u, values)``."""
        alpha = 1.0
        for _ in range(12):
            u_t = u + alpha * du
            values = self._values(u_t, rho, simp, tangent=alpha == 1.0)
            if values.forces is None:
                alpha *= 0.5
                continue
            energy = float(values.energy.sum() - target_f @ u_t)
            r_t = self.bc.homogenize(assemble_vector(self.dofs, values.forces, self.size) - target_f)
            if (energy <= energy0 + 1e-4 * alpha * slope0
                    or float(np.linalg.norm(r_t)) < (1.0 - 1e-4 * alpha) * norm0):
                if values.tangents is None:
                    values = self._values(u_t, rho, simp, tangent=True)
                return u_t, values
            curvature = 2.0 * (energy - energy0 - slope0 * alpha)
            guess = -slope0 * alpha * alpha / curvature if curvature > 0 else 0.5 * alpha
            alpha = float(np.clip(guess, 0.1 * alpha, 0.5 * alpha))
        raise StepFailed("line search found no decrease", u + du)
