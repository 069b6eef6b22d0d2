"""What every hyperelastic Q1 element of the finite-strain structure shares (total Lagrangian).

A material kernel (:class:`~tofsi.fem.neo_hookean.NeoHookeanKernel`,
:class:`~tofsi.fem.saint_venant_kirchhoff.SaintVenantKirchhoffKernel`) is a
:class:`HyperelasticKernel` that writes the nonlinear element per unit Young's
modulus -- ``nonlinear(ue, tangent)``: internal forces ``R_NL``, tangents
``K_NL``, smallest ``det F`` and energies ``W_NL`` of element displacements
``ue`` ``(E, 8)``, and ``nonlinear_energy(ue)`` -- on the reference geometry
this class tabulates once: 2x2 Gauss points, weights ``w det J0``, reference
shape gradients ``G_aJ = dN_a/dX_J`` and the small-strain stiffness ``K0`` per
unit modulus (``lam, mu`` = :func:`~tofsi.fem.elasticity.lame` of ``(1, nu)``).

Nearly void elements: the energy interpolation of Wang, Lazarov, Sigmund &
Jensen (2014, Comput. Methods Appl. Mech. Engrg. 276, 453-472), the same for
every material. With the element modulus ``E_e = E(rho_e)`` and ``g_e = g(rho_e)``
in [0, 1] (1: solid, fully nonlinear; 0: void, linear) the element energy is

    W_e(u) = E_e [W_NL(g u) - W_L(g u) + W_L(u)],      W_L(u) = 1/2 u . K0 u,

so ``R_e = E_e [g R_NL(g u) + (1 - g^2) K0 u]``, ``K_e = E_e [g^2 K_NL(g u) + (1 - g^2) K0]`` and

    dR_e/drho_e = E'_e [g R_NL(g u) + (1 - g^2) K0 u] + E_e g'_e [R_NL(g u) + g K_NL(g u) u - 2 g K0 u].

``g = 1`` everywhere is plain SIMP at finite strain; ``g = 0`` is the linear
element exactly (every material's tangent at ``u = 0`` is ``K0``). Every
function is complex-safe in ``u``, the modulus and ``g`` (complex-step
checks); inversion (``det F <= 0`` at a Gauss point of the nonlinear part) is
judged on the real part and reported, not evaluated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from tofsi.fem.elasticity import element_stiffness, lame
from tofsi.fem.geometry import jacobians
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions


@dataclass(frozen=True)
class NonlinearWeight:
    """The weight ``g(rho)`` of the nonlinear energy (Wang et al. 2014), a smoothed Heaviside::

        g(rho) = [tanh(beta rho0) + tanh(beta (rho - rho0))] / [tanh(beta rho0) + tanh(beta (1 - rho0))]

    ``g(0) = 0`` (void: linear), ``g(1) = 1`` (solid: nonlinear); ``threshold`` ``rho0``
    and ``sharpness`` ``beta`` (Wang et al.: 0.01 and 500).
    """

    threshold: float = 0.01
    sharpness: float = 500.0

    def __call__(self, rho):
        b, r0 = self.sharpness, self.threshold
        return (math.tanh(b * r0) + np.tanh(b * (np.asarray(rho) - r0))) / (math.tanh(b * r0) + math.tanh(b * (1 - r0)))

    def derivative(self, rho):
        b, r0 = self.sharpness, self.threshold
        t = np.exp(-2.0 * np.abs(b * (np.asarray(rho) - r0)))            # sech^2 z = 4 t / (1 + t)^2, no overflow
        return b * 4.0 * t / (1.0 + t) ** 2 / (math.tanh(b * r0) + math.tanh(b * (1 - r0)))


class ElementValues(NamedTuple):
    """One evaluation of a batch of elements; forces, tangents and energy are None when the
    nonlinear part inverts an element (``det F <= 0`` at a Gauss point: the energy is undefined)."""

    forces: np.ndarray | None        # (E, 8) [N/m]
    tangents: np.ndarray | None      # (E, 8, 8) [N/m^2] (None when not asked for)
    det_min: np.ndarray              # (E,) smallest det F of the nonlinear part
    energy: np.ndarray | None        # (E,) [J/m]


class HyperelasticKernel:
    """Geometry tables and the energy interpolation of a fixed reference mesh of Q1 quads.

    Xe : reference corners ``(E, 4, 2)`` [m]; poisson_ratio : ``nu`` (the Lame
    parameters are per unit Young's modulus; moduli are per-element inputs);
    K0 : the small-strain stiffness per unit modulus ``(E, 8, 8)`` if already made.
    Subclasses write :meth:`nonlinear` and :meth:`nonlinear_energy` and name their ``material``.
    """

    material = ""

    def __init__(self, Xe: np.ndarray, poisson_ratio: float, K0: np.ndarray | None = None):
        points, weights = gauss_square(2)
        Xe = np.asarray(Xe, dtype=float)
        _, dN = shape_functions(1, points)                             # (G, 4, 2) reference gradients
        _, det0, inv = jacobians(Xe, points)                           # (E, G), (E, G, 2, 2): B = dxi/dX
        E, G = det0.shape
        self.n_elements, self.n_points = E, G
        self.shape_gradients = dN                                      # dN_am (G, 4, 2) on the unit square
        self.inverse_jacobians = inv                                   # B_mJ (E, G, 2, 2)
        self.grad = np.matmul(dN, inv)                                 # (E, G, 4, 2) G_aJ = dN_am B_mJ
        self.grad_rows = np.ascontiguousarray(self.grad.transpose(0, 2, 3, 1).reshape(E, 4, 2 * G))   # [e, a, (J, g)]
        self.weight = det0 * weights                                   # (E, G) w det J0 [m^2]
        self.lam, self.mu = lame(1.0, poisson_ratio)
        self.K0 = element_stiffness(Xe, self.lam, self.mu) if K0 is None else K0   # (E, 8, 8) per unit modulus

    # ---- kinematics -------------------------------------------------------------------------
    def displacement_gradient(self, ue: np.ndarray) -> np.ndarray:
        """``H = grad_X u`` as ``(E, i, J, G)`` at the Gauss points of element displacements ``(E, 8)``."""
        E, G = self.n_elements, self.n_points
        U = np.asarray(ue).reshape(E, 4, 2)                           # (E, a, i)
        return np.matmul(U.swapaxes(1, 2), self.grad_rows).reshape(E, 2, 2, G)

    def deformation_gradient(self, ue: np.ndarray) -> np.ndarray:
        """``F = I + grad_X u`` ``(E, G, 2, 2)`` at the Gauss points of element displacements ``(E, 8)``."""
        F = self.displacement_gradient(ue).transpose(0, 3, 1, 2).copy()
        F[..., 0, 0] += 1.0
        F[..., 1, 1] += 1.0
        return F

    def linear_forces(self, ue: np.ndarray) -> np.ndarray:
        """``K0 u`` ``(E, 8)`` per unit modulus."""
        return np.einsum("eab,eb->ea", self.K0, ue)

    # ---- the material (per unit modulus) ------------------------------------------------------
    def nonlinear(self, ue: np.ndarray, tangent: bool = True) -> ElementValues:
        """The material's internal forces, tangents (if ``tangent``), smallest ``det F`` and
        energies of element displacements ``ue`` ``(E, 8)``, per unit modulus."""
        raise NotImplementedError

    def nonlinear_energy(self, ue: np.ndarray) -> np.ndarray:
        """``int W_NL dV`` per element ``(E,)`` [J/m per Pa]; NaN where an element is inverted."""
        raise NotImplementedError

    # ---- the energy-interpolated element ------------------------------------------------------
    def evaluate(self, ue: np.ndarray, modulus, g, tangent: bool = True) -> ElementValues:
        """Interpolated internal forces ``(E, 8)``, tangents ``(E, 8, 8)`` (if ``tangent``),
        smallest ``det F`` of the nonlinear part ``g u`` and energies ``W_e`` ``(E,)``.

        modulus : ``E(rho)`` ``(E,)`` [Pa]; g : ``g(rho)`` ``(E,)`` (ones: plain SIMP).
        """
        modulus, g = np.asarray(modulus), np.asarray(g)
        Rn, Kn, det_min, Wn = self.nonlinear(g[:, None] * ue, tangent)
        if Rn is None:
            return ElementValues(None, None, det_min, None)
        linear = 1.0 - g * g                                           # (E,)
        K0u = self.linear_forces(ue)
        Re = modulus[:, None] * (g[:, None] * Rn + linear[:, None] * K0u)
        We = modulus * (Wn + 0.5 * linear * np.einsum("ea,ea->e", ue, K0u))
        if not tangent:
            return ElementValues(Re, None, det_min, We)
        Kn *= (modulus * g * g)[:, None, None]                         # Kn is this call's own array
        Kn += (modulus * linear)[:, None, None] * self.K0
        return ElementValues(Re, Kn, det_min, We)

    def density_vectors(self, ue: np.ndarray, modulus, dmodulus, g, dg) -> np.ndarray:
        """``dR_e/drho_e`` ``(E, 8)`` from ``E(rho)``, ``E'(rho)``, ``g(rho)``, ``g'(rho)`` ``(E,)``
        (the formula in the module docstring); NaN where the nonlinear part is inverted."""
        modulus, dmodulus, g, dg = (np.asarray(a) for a in (modulus, dmodulus, g, dg))
        Rn, Kn, _, _ = self.nonlinear(g[:, None] * ue)
        if Rn is None:
            return np.full(np.shape(ue), np.nan)
        K0u = self.linear_forces(ue)
        Knu = np.einsum("eab,eb->ea", Kn, ue)
        forces = g[:, None] * Rn + (1.0 - g * g)[:, None] * K0u
        return dmodulus[:, None] * forces + (modulus * dg)[:, None] * (Rn + g[:, None] * (Knu - 2.0 * K0u))

    def energy(self, ue: np.ndarray, modulus, g) -> np.ndarray:
        """Element strain energy ``W_e(u)`` ``(E,)`` [J/m]: ``E [W_NL(g u) - W_L(g u) + W_L(u)]``."""
        modulus, g = np.asarray(modulus), np.asarray(g)
        W_L = 0.5 * np.einsum("ea,ea->e", ue, self.linear_forces(ue))
        return modulus * (self.nonlinear_energy(g[:, None] * ue) + (1.0 - g * g) * W_L)
