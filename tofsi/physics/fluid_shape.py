"""Analytic shape derivatives of the fluid element quantities with respect to the corners ``Xe``.

Moving corner ``k`` of an element by ``e_m`` moves its points by the field
``V = M_k e_m`` (``M`` the Q1 shape functions that define the geometry).
The reference basis does not move, so with ``g_k = grad M_k`` (physical)

    d(det J)           = det J g_km,
    d(dN_b/dx_j)       = -(dN_b/dx_m) g_kj,                 (d(J^-1) = -J^-1 dJ J^-1)
    d(d2N_b/dx_i dx_j) = -(d2M_k/dx_i dx_j) dN_b/dx_m - g_kj d2N_b/dx_i dx_m - g_ki d2N_b/dx_m dx_j,

and for a field ``v = sum_b v_b N_b``: ``dv = 0``, ``dL_ij = -L_im g_kj``
(``L = grad v``), ``d div v = -sum_i L_im g_ki``. Every derivative here is
those rules applied term by term to the integrand of
:func:`tofsi.physics.fluid_kernel.fluid_element`, of the load operators of
:mod:`tofsi.physics.fluid_load` and of the dissipation functional; a kernel
makes the basis of the configuration once (:func:`element_basis`) and
every term, the value's and the derivative's, uses it. The column of a
derivative is the corner coordinate ``2 k + m`` (the order of
:func:`tofsi.fem.complex_step.corner_derivatives`, the tests' oracle).
All kernels are batched over the elements (``E``) and the 3x3 Gauss points
(``G``): a few batched products per term group, no loop over elements.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.geometry import jacobians, physical_hessians
from tofsi.fem.shapes import shape_functions
from tofsi.physics.fluid_kernel import N1, N2, POINTS, WEIGHTS

_, DN2 = shape_functions(2, POINTS)                  # (G, 9, 2) reference gradients
_, DN1 = shape_functions(1, POINTS)                  # (G, 4, 2)


def _pair(A, B):
    """``sum_j A[..., a, j] B[..., b, j]`` ``(..., a, b)``."""
    return np.matmul(A, np.swapaxes(B, -1, -2))


def _outer(A, B):
    """``A[..., a] B[..., b]`` ``(..., a, b)`` as a batched product (faster than broadcasting
    over short trailing axes)."""
    return np.matmul(A[..., :, None], B[..., None, :])


def element_basis(Xe):
    """The per-configuration basis ``(g2, g1, w)``: physical gradients of the Q2 ``(E, G, 9, 2)``
    and Q1 ``(E, G, 4, 2)`` shape functions and the quadrature weights ``w = W det J``
    ``(E, G)`` [m^2] of corners ``Xe`` ``(E, 4, 2)``."""
    _, det, inv = jacobians(Xe, POINTS)
    return np.matmul(DN2, inv), np.matmul(DN1, inv), det * WEIGHTS


def _sum_points(A, B):
    """``sum_g A[e, g, r] B[e, g, c]`` ``(E, R, C)`` for ``A`` ``(E, G, ...)``, ``B`` ``(E, G, ...)``."""
    E, G = A.shape[:2]
    return np.matmul(A.reshape(E, G, -1).transpose(0, 2, 1), B.reshape(E, G, -1))


def fluid_shape(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False):
    """Element residuals ``R_e`` ``(E, 22)`` and their shape derivatives ``dR_e/dXe`` ``(E, 22, 8)``.

    The residual of :func:`~tofsi.physics.fluid_kernel.fluid_element` (same
    arguments, same units), differentiated with respect to the corners.
    With ``s = rho_f L v + alpha v`` and ``T = mu L (+ mu L^T) - p I``,
    ``R_v[a, i] = int N_a s_i + T_ij dN_a/dx_j`` and
    ``R_p[c] = -int M_c div v``; per corner coordinate ``(k, m)``

        dR_v[a, i] = int g_km (N_a s_i + T_ij dN_a/dx_j) + N_a ds_i + dT_ij dN_a/dx_j
                     - (dN_a/dx_m) T_ij g_kj,
        ds_i  = -rho_f L_im (g_k . v),
        dT_ij = -mu L_im g_kj (- mu L_jm g_ki, symmetric form),
        dR_p[c] = -int M_c (g_km div v - L_im g_ki).

    The terms are grouped by the pair of indices their products couple, one
    batched product over the Gauss points each: ``(a, i)`` with ``(k, m)``
    (``d det J``, the source), ``(a, k)`` with ``(i, m)`` (the stress and the
    convection), ``(a, m)`` with ``(i, k)`` (the moving test gradients).
    """
    E = Xe.shape[0]
    mu = viscosity
    g2, g1, w = element_basis(Xe)
    G = w.shape[1]
    v = np.matmul(N2, ve)                                            # (E, G, 2)
    L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], g2)               # L_ij = dv_i/dx_j (E, G, 2, 2)
    LT = np.ascontiguousarray(np.swapaxes(L, -1, -2))
    p = np.matmul(pe, N1.T)                                          # (E, G)
    div = L[..., 0, 0] + L[..., 1, 1]
    s = density * _pair(L, v[:, :, None])[..., 0] + alpha[:, None, None] * v     # (E, G, 2)
    TT = mu * (LT + L if symmetric else LT) - p[..., None, None] * np.eye(2)     # T^T (E, G, 2, 2)
    gT = np.matmul(g2, TT)                                           # T_ij dN_a/dx_j (E, G, 9, 2)
    wg = g1 * w[..., None, None]                                     # w g_kj (E, G, 4, 2)
    Re = np.empty((E, 22), dtype=np.result_type(Xe, ve, pe))
    Re[:, :18] = (np.matmul(N2.T, s * w[..., None]) + np.einsum("egai,eg->eai", gT, w)).reshape(E, 18)
    Re[:, 18:] = -np.matmul(div * w, N1)
    dR = np.empty((E, 22, 8), dtype=Re.dtype)
    # (a, i) x (k, m): g_km (N_a s_i + T_ij dN_a/dx_j)
    dv = np.matmul(N2.T, _outer(s, wg.reshape(E, G, 8)).reshape(E, G, 16)).reshape(E, 18, 8) + _sum_points(gT, wg)
    # (a, k) x (i, m): -[mu g_k . grad N_a + rho_f N_a (g_k . v)] L_im
    X = mu * _pair(g2, wg)                                           # (E, G, 9, 4)
    if density:
        X += density * _outer(np.broadcast_to(N2, (E, G, 9)), _pair(wg, v[:, :, None])[..., 0])
    dv -= _sum_points(X, L).reshape(E, 9, 4, 2, 2).transpose(0, 1, 3, 2, 4).reshape(E, 18, 8)
    # (a, m) x (i, k): -(dN_a/dx_m) (T g_k)_i (- mu (grad N_a . L_:m) g_ki, symmetric form)
    Y = _sum_points(g2, np.matmul(np.swapaxes(TT, -1, -2), np.swapaxes(wg, -1, -2)))
    if symmetric:
        Y += mu * _sum_points(np.matmul(g2, L), np.swapaxes(wg, -1, -2))
    dv -= Y.reshape(E, 9, 2, 2, 4).transpose(0, 1, 3, 4, 2).reshape(E, 18, 8)
    dR[:, :18] = dv
    # M_c: -g_km div v + L_im g_ki
    dR[:, 18:] = np.matmul(N1.T, (np.matmul(wg, L) - div[..., None, None] * wg).reshape(E, G, 8))
    return Re, dR


def mass_shape(Xe, ve):
    """``d(A_e w_e)/dXe`` ``(E, 18, 8)`` with ``(A_e w_e)[b, i] = int N_b v_i`` (only ``det J`` moves)."""
    E = Xe.shape[0]
    _, g1, w = element_basis(Xe)
    v = np.matmul(N2, ve)
    wg = (g1 * w[..., None, None]).reshape(E, -1, 8)
    return np.matmul(N2.T, _outer(v, wg).reshape(E, -1, 16)).reshape(E, 18, 8)


def dissipation_shape(Xe, ve, alpha, viscosity: float):
    """``d phi_e/dXe`` ``(E, 8)`` of ``phi_e = 1/2 int mu L:L + alpha |v|^2``:

        d phi_e = int g_km (mu L:L + alpha |v|^2) / 2 - mu (L^T L g_k)_m.
    """
    E = Xe.shape[0]
    g2, g1, w = element_basis(Xe)
    v = np.matmul(N2, ve)
    L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], g2)
    power = 0.5 * (viscosity * np.sum(L * L, axis=(-1, -2)) + alpha[:, None] * np.sum(v * v, axis=-1))
    wg = g1 * w[..., None, None]
    moved = power[..., None, None] * wg - viscosity * np.matmul(wg, np.matmul(np.swapaxes(L, -1, -2), L))
    return moved.sum(axis=1).reshape(E, 8)


def stress_load_shape(Xe, ve, pe, viscosity: float):
    """``d(B_e w_e)/dXe`` ``(E, 8, 8)`` of the stress-divergence load (:func:`~tofsi.physics.
    fluid_load.load_operator`): ``f[a, i] = int sigma_ij dM_a/dx_j + M_a (div sigma)_i`` with
    ``sigma = -p I + mu (L + L^T)`` and ``div sigma = -grad p + mu (lap v + grad div v)``.

    Besides ``d(det J)`` and the moving gradients, the second derivatives of
    ``v`` move: with ``H_ijl = d2v_i/dx_j dx_l`` and ``K_k`` the Hessian of ``M_k``,
    ``dH_ijl = -K_kjl L_im - g_kl H_ijm - g_kj H_iml`` and ``d(dp/dx_i) = -(dp/dx_m) g_ki``, so

        d(div sigma)_i = (dp/dx_m) g_ki - mu [(lap M_k) L_im + 2 g_kj H_ijm
                         + K_kij L_jm + g_kj H_jim + g_ki (grad div v)_m].
    """
    E = Xe.shape[0]
    mu = viscosity
    g2, g1, w = element_basis(Xe)
    G = w.shape[1]
    K = physical_hessians(Xe, 1, POINTS, g1)                        # (E, G, 4, 2, 2)
    H = np.einsum("ebi,egbjl->egijl", ve, physical_hessians(Xe, 2, POINTS, g2))   # (E, G, 2, 2, 2)
    L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], g2)               # (E, G, 2, 2)
    gp = np.matmul(pe[:, None, None, :], g1)[:, :, 0]               # grad p (E, G, 2)
    p = np.matmul(pe, N1.T)
    sigma = mu * (L + np.swapaxes(L, -1, -2)) - p[..., None, None] * np.eye(2)
    graddiv = H[:, :, 0, :, 0] + H[:, :, 1, :, 1]                   # d/dx_i div v (E, G, 2)
    ds = -gp + mu * (H[..., 0, 0] + H[..., 1, 1] + graddiv)         # div sigma (E, G, 2)
    wg = g1 * w[..., None, None]
    wgT = np.swapaxes(wg, -1, -2)                                    # (E, G, 2, 4)
    g1T = np.swapaxes(g1, -1, -2)
    # against dM_a/dx_j (sum over g, j), [j, i, k, m]: g_km sigma_ij + d sigma_ij - delta_jm (sigma g_k)_i
    Z = _outer(sigma.reshape(E, G, 4), wg.reshape(E, G, 8)).reshape(E, G, 2, 2, 4, 2)
    Z -= mu * np.matmul(wgT[:, :, :, None, :, None], L[:, :, None, :, None, :])
    Z -= mu * np.matmul(wgT[:, :, None, :, :, None], L[:, :, :, None, None, :])
    sg = _pair(sigma, wg)                                             # w (sigma g_k)_i (E, G, 2, 4)
    Z[:, :, 0, :, :, 0] -= sg
    Z[:, :, 1, :, :, 1] -= sg
    # against M_a, [i, k, m]: g_km (div sigma)_i + d(div sigma)_i
    lapK = K[..., 0, 0] + K[..., 1, 1]                               # (E, G, 4)
    dds = (g1T[..., None] * (gp - mu * graddiv)[:, :, None, None, :]
           - mu * (lapK[:, :, None, :, None] * L[:, :, :, None, :]
                   + 2.0 * np.matmul(g1[:, :, None], H)
                   + np.matmul(K, L[:, :, None]).transpose(0, 1, 3, 2, 4)
                   + np.matmul(g1[:, :, None], np.swapaxes(H, 2, 3))))
    Y = _outer(ds, wg.reshape(E, G, 8)).reshape(E, G, 2, 4, 2) + dds * w[..., None, None, None]
    df = (np.matmul(g1.transpose(0, 2, 1, 3).reshape(E, 4, 2 * G), Z.reshape(E, 2 * G, 16))
          + np.matmul(N1.T, Y.reshape(E, G, 16)))
    return df.reshape(E, 8, 8)
