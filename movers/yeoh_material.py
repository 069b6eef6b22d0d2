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
Voigt order (11, 22, 12) with engineering shear ``2 E12``.

The mover's kernel needs the first Piola-Kirchhoff stress ``P = F S`` and the
first elasticity tensor ``A_iJkL = dP_iJ/dF_kL = F_iI D_IJKL F_kK + delta_ik S_JL``.
With ``F C^-1 = F^-T`` and ``F C^-1 F^T = I`` the push-forward of each term
of ``D`` is a product of 2x2 matrices, so (``Y = F dJ1 = a (F - I1/3 F^-T)``)

    P = 2 W1 Y + 2 kappa (J3 - 1) J3 F^-T,
    A_iJkL = 4 W11 Y_iJ Y_kL + c_x (F_iJ F^-T_kL + F^-T_iJ F_kL) + c_cc F^-T_iJ F^-T_kL
             + c_s F^-T_iL F^-T_kJ + delta_ik (c_s C^-1 + S)_JL,

with ``c_x = -4 W1 a / 3``, ``c_cc = 4 W1 a I1 / 9 + 2 kappa (2 J3^2 - J3)``,
``c_s = 2 W1 a I1 / 3 - 2 kappa (J3^2 - J3)`` (:func:`piola_and_elasticity`).
Small strain:
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


def stress_and_tangent(F, A10, A20, A30, kappa):
    """Second Piola-Kirchhoff stress ``S`` (..., 2, 2) and Voigt tangent ``D`` (..., 3, 3).

    ``A20`` may be an array broadcasting against ``F.shape[:-2]`` (stiffening).
    The tangent is the formula of the module docstring with the coefficients
    of each tensor product collected:
    ``D = 4 W11 dJ1 (x) dJ1 - (4 W1 a / 3)(I (x) C^-1 + C^-1 (x) I) + c1 C^-1 (x) C^-1 + c2 Csym``.
    The material form in the reference configuration; the mover's kernel uses its
    push-forward :func:`piola_and_elasticity` (the two are tested against each other).
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


def _pull(X, B):
    """``X B^T`` for component-first 2x2 tensors ``(2, 2, N)``."""
    return np.einsum("iJn,mJn->imn", X, B)


BLOCKS = ((0, 0), (0, 1), (1, 1))     # the blocks (i, k) of A that are computed


def piola_and_elasticity(F, A10, A20, A30, kappa, pull=None, weight=None, tangent=True, out=None):
    """First Piola-Kirchhoff stress and first elasticity tensor, pulled back by ``pull``.

    Component-first layout: ``F`` ``(2, 2, N)`` (each component one contiguous
    array over N points); ``A20`` a scalar or ``(N,)``; ``pull`` ``B`` ``(2, 2, N)``
    (default the identity) and ``weight`` ``w`` ``(N,)`` (default 1). Returns

        Pt_im = w P_iJ B_mJ                      (2, 2, N)
        At_ikmn = w A_iJkL B_mJ B_nL             (3, 2, 2, N), or None without ``tangent``,

    by the formulas of the module docstring; ``At`` holds the blocks ``(i, k)`` of
    :data:`BLOCKS` (the fourth is ``At_10mn = At_01nm``) and is written into
    ``out`` when given (any array, or strided view, of that shape). With ``B = dxi/dX``
    (the inverse Jacobian of an element map) and ``w`` the quadrature weight times
    ``det dX/dxi``, contracting with reference shape gradients gives the
    element's internal forces and tangent directly (:mod:`movers.yeoh_kernel`).
    Complex ``A20`` is allowed (complex step in the stiffening).
    """
    F00, F01, F10, F11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    J = F00 * F11 - F01 * F10
    Fit = np.array([[F11, -F10], [-F01, F00]]) / J                  # F^-T
    I1 = F00 * F00 + F01 * F01 + F10 * F10 + F11 * F11 + 1.0
    a = 1.0 / np.cbrt(J * J)
    t = I1 * a - 3.0
    W1 = A10 + 2.0 * A20 * t + 3.0 * A30 * t**2
    p = 2.0 * kappa * (J - 1.0) * J
    Y = a * (F - (I1 / 3.0) * Fit)
    w = 1.0 if weight is None else weight
    if pull is not None:
        F, Y, Fit = _pull(F, pull), _pull(Y, pull), _pull(Fit, pull)
    Pt = (2.0 * W1 * w) * Y + (p * w) * Fit
    if not tangent:
        return Pt, None
    W11 = 2.0 * A20 + 6.0 * A30 * t
    c_x = -4.0 * W1 * a / 3.0 * w
    c_cc = (4.0 * W1 * a * I1 / 9.0 + 2.0 * kappa * (2.0 * J**2 - J)) * w
    c_s = (2.0 * W1 * a * I1 / 3.0 - 2.0 * kappa * (J**2 - J)) * w
    # A = sum_p V_p (x) U_p + c_s F^-T_iL F^-T_kJ + delta_ik (c_s C^-1 + S)_JL with V = (Y, F, F^-T)
    # and U = (4 W11 Y, c_x F^-T, c_x F + c_cc F^-T): the three dyads of the module docstring's formula
    pairs = ((Y, (4.0 * W11 * w) * Y), (F, c_x * Fit), (Fit, c_x * F + c_cc * Fit))
    crossed = c_s * Fit
    # C^-1 = F^-1 F^-T (pulled back with Fit already), S = 2 W1 a (I - I1/3 C^-1) + p C^-1
    Cinv = np.einsum("iJn,iLn->JLn", Fit, Fit)
    eye = np.eye(2)[:, :, None] if pull is None else np.einsum("mJn,qJn->mqn", pull, pull)
    Z = (c_s - 2.0 * W1 * a * I1 / 3.0 * w + p * w) * Cinv + (2.0 * W1 * a * w) * eye
    At = np.empty((3, 2, 2) + J.shape, dtype=Pt.dtype) if out is None else out
    for b, (i, k) in enumerate(BLOCKS):          # entry by entry: no (3, 2, 2, N) temporaries
        for m, n in ((0, 0), (0, 1), (1, 0), (1, 1)):
            if i == k and m > n:                   # the diagonal blocks are symmetric in (m, n)
                At[b, m, n] = At[b, n, m]
                continue
            acc = crossed[i, n] * Fit[k, m]
            for V, U in pairs:
                acc += V[i, m] * U[k, n]
            if i == k:
                acc += Z[m, n]
            At[b, m, n] = acc
    return Pt, At
