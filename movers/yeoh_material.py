"""Yeoh hyperelastic material in plane strain: energy, stress, tangent.

``F`` is the in-plane 2x2 deformation gradient, embedded with ``F33 = 1``;
``C = F^T F``, ``I1 = C11 + C22 + 1`` (the out-of-plane stretch counts),
``I3 = det C = J^2``, reduced invariants ``J1 = I1 I3^(-1/3)``, ``J3 = J``:

    W = A10 (J1 - 3) + A20 (J1 - 3)^2 + A30 (J1 - 3)^3 + kappa (J3 - 1)^2.

With ``W1 = dW/dJ1``, ``W11 = d2W/dJ1^2``, ``a = I3^(-1/3)``:

    S = 2 dW/dC = 2 W1 a (I - I1/3 C^-1) + 2 kappa (J3 - 1) J3 C^-1,
    D = 4 d2W/dC2 = 4 [W11 dJ1 (x) dJ1 + W1 d2J1]
        + 2 kappa [(2 J3^2 - J3) C^-1 (x) C^-1 - (J3^2 - J3) Csym],
    dJ1 = a (I - I1/3 C^-1),
    d2J1 = -(a/3)(I (x) C^-1 + C^-1 (x) I) + (a I1/9) C^-1 (x) C^-1 + (a I1/6) Csym,
    Csym_ijkl = C^-1_ik C^-1_jl + C^-1_il C^-1_jk.

Only the in-plane components are needed (C is block diagonal with C33 = 1).
Voigt order (11, 22, 12) with engineering shear ``2 E12``. Small strain:
shear modulus ``mu = 2 A10``, bulk modulus ``K = 2 kappa``. Units: the A's and
kappa are stresses [Pa]; only their ratios matter for mesh motion.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.geometry import inverse_2x2

_I = np.array([0, 1, 0])            # first index of Voigt entry p
_J = np.array([0, 1, 1])            # second index


def invariants(F: np.ndarray):
    """``C`` (..., 2, 2), ``C^-1``, ``I1``, ``I3`` of in-plane deformation gradients."""
    C = np.matmul(np.swapaxes(F, -1, -2), F)
    I3, Cinv = inverse_2x2(C)
    I1 = C[..., 0, 0] + C[..., 1, 1] + 1.0
    return C, Cinv, I1, I3


def energy(F, A10, A20, A30, kappa):
    """Strain energy density ``W`` (...,) [Pa]."""
    _, _, I1, I3 = invariants(F)
    t = I1 * I3 ** (-1.0 / 3.0) - 3.0
    J = np.sqrt(I3)
    return A10 * t + A20 * t**2 + A30 * t**3 + kappa * (J - 1.0) ** 2


def _voigt(A):
    """Symmetric 2x2 tensors (..., 2, 2) as (..., 3) in the order (11, 22, 12)."""
    return A[..., _I, _J]


def _outer(a, b):
    """``(A (x) B)`` in Voigt form from Voigt vectors ``a``, ``b`` (..., 3)."""
    return a[..., :, None] * b[..., None, :]


def _sym(v):
    """``A_ik A_jl + A_il A_jk`` in Voigt form (..., 3, 3) for symmetric ``A = (a, b, c)``."""
    a, b, c = v[..., 0], v[..., 1], v[..., 2]
    out = np.empty(v.shape[:-1] + (3, 3), dtype=v.dtype)
    out[..., 0, 0] = 2 * a * a
    out[..., 1, 1] = 2 * b * b
    out[..., 2, 2] = a * b + c * c
    out[..., 0, 1] = out[..., 1, 0] = 2 * c * c
    out[..., 0, 2] = out[..., 2, 0] = 2 * a * c
    out[..., 1, 2] = out[..., 2, 1] = 2 * b * c
    return out


def stress(F, A10, A20, A30, kappa):
    """Second Piola-Kirchhoff stress ``S`` (..., 2, 2) alone (no tangent)."""
    _, Cinv, I1, I3 = invariants(F)
    a = 1.0 / np.cbrt(I3)
    J = np.sqrt(I3)
    t = I1 * a - 3.0
    W1 = A10 + 2.0 * A20 * t + 3.0 * A30 * t**2
    eye = np.eye(2)
    return (2.0 * W1 * a)[..., None, None] * (eye - (I1 / 3.0)[..., None, None] * Cinv) \
        + (2.0 * kappa * (J - 1.0) * J)[..., None, None] * Cinv


def stress_and_tangent(F, A10, A20, A30, kappa):
    """Second Piola-Kirchhoff stress ``S`` (..., 2, 2) and Voigt tangent ``D`` (..., 3, 3).

    ``A20`` may be an array broadcasting against ``F.shape[:-2]`` (stiffening).
    The tangent is the formula of the module docstring with the coefficients
    of each tensor product collected:
    ``D = 4 W11 dJ1 (x) dJ1 - (4 W1 a / 3)(I (x) C^-1 + C^-1 (x) I) + c1 C^-1 (x) C^-1 + c2 Csym``.
    """
    C, Cinv, I1, I3 = invariants(F)
    a = 1.0 / np.cbrt(I3)
    J = np.sqrt(I3)
    t = I1 * a - 3.0
    W1 = A10 + 2.0 * A20 * t + 3.0 * A30 * t**2
    W11 = 2.0 * A20 + 6.0 * A30 * t
    eye = np.array([1.0, 1.0, 0.0])
    ci = _voigt(Cinv)                                                # (..., 3)
    dJ1 = a[..., None] * (eye - (I1 / 3.0)[..., None] * ci)          # (..., 3)
    s = 2.0 * W1[..., None] * dJ1 + (2.0 * kappa * (J - 1.0) * J)[..., None] * ci
    S = s[..., [[0, 2], [2, 1]]]
    c_cross = -4.0 * W1 * a / 3.0
    c_cc = 4.0 * W1 * a * I1 / 9.0 + 2.0 * kappa * (2.0 * J**2 - J)
    c_sym = 2.0 * W1 * a * I1 / 3.0 - 2.0 * kappa * (J**2 - J)
    cross = _outer(eye, ci)
    D = ((4.0 * W11)[..., None, None] * _outer(dJ1, dJ1)
         + c_cross[..., None, None] * (cross + np.swapaxes(cross, -1, -2))
         + c_cc[..., None, None] * _outer(ci, ci) + c_sym[..., None, None] * _sym(ci))
    return S, D
