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

VOIGT = ((0, 0), (1, 1), (0, 1))


def invariants(F: np.ndarray):
    """``C`` (..., 2, 2), ``C^-1``, ``I1``, ``I3`` of in-plane deformation gradients."""
    C = np.einsum("...ki,...kj->...ij", F, F)
    I3 = C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] * C[..., 1, 0]
    Cinv = np.empty_like(C)
    Cinv[..., 0, 0] = C[..., 1, 1] / I3
    Cinv[..., 1, 1] = C[..., 0, 0] / I3
    Cinv[..., 0, 1] = -C[..., 0, 1] / I3
    Cinv[..., 1, 0] = -C[..., 1, 0] / I3
    I1 = C[..., 0, 0] + C[..., 1, 1] + 1.0
    return C, Cinv, I1, I3


def energy(F, A10, A20, A30, kappa):
    """Strain energy density ``W`` (...,) [Pa]."""
    _, _, I1, I3 = invariants(F)
    t = I1 * I3 ** (-1.0 / 3.0) - 3.0
    J = np.sqrt(I3)
    return A10 * t + A20 * t**2 + A30 * t**3 + kappa * (J - 1.0) ** 2


def stress_and_tangent(F, A10, A20, A30, kappa):
    """Second Piola-Kirchhoff stress ``S`` (..., 2, 2) and Voigt tangent ``D`` (..., 3, 3).

    ``A20`` may be an array broadcasting against ``F.shape[:-2]`` (stiffening).
    """
    C, Cinv, I1, I3 = invariants(F)
    a = I3 ** (-1.0 / 3.0)
    J = np.sqrt(I3)
    t = I1 * a - 3.0
    W1 = A10 + 2.0 * A20 * t + 3.0 * A30 * t**2
    W11 = 2.0 * A20 + 6.0 * A30 * t
    eye = np.broadcast_to(np.eye(2), C.shape)
    dJ1 = a[..., None, None] * (eye - (I1 / 3.0)[..., None, None] * Cinv)
    S = 2.0 * W1[..., None, None] * dJ1 + (2.0 * kappa * (J - 1.0) * J)[..., None, None] * Cinv

    def outer(A, B):                    # (A (x) B) in Voigt form
        return np.stack([np.stack([A[..., i, j] * B[..., k, l] for (k, l) in VOIGT], -1)
                         for (i, j) in VOIGT], -2)

    def sym(A):                         # A_ik A_jl + A_il A_jk in Voigt form
        return np.stack([np.stack([A[..., i, k] * A[..., j, l] + A[..., i, l] * A[..., j, k]
                                   for (k, l) in VOIGT], -1) for (i, j) in VOIGT], -2)

    CC, Csym = outer(Cinv, Cinv), sym(Cinv)
    d2J1 = (-(a / 3.0)[..., None, None] * (outer(eye, Cinv) + outer(Cinv, eye))
            + (a * I1 / 9.0)[..., None, None] * CC + (a * I1 / 6.0)[..., None, None] * Csym)
    D = (4.0 * (W11[..., None, None] * outer(dJ1, dJ1) + W1[..., None, None] * d2J1)
         + 2.0 * kappa * ((2.0 * J**2 - J)[..., None, None] * CC - (J**2 - J)[..., None, None] * Csym))
    return S, D
