"""The fluid's force on the structure in the unified domain (density-weighted volume form).

With a sharp interface the fluid pulls on the solid with the traction
``sigma n_s`` (``n_s`` the solid's outward normal); its virtual work is
``int_Gamma w . sigma n_s``. With a solid indicator ``Psi`` (1 in solid, 0 in
fluid) the divergence theorem turns it into a volume integral,

    f(w_s) = int Psi [ sigma_ij dw_i/dx_j + w_i d sigma_ij/dx_j ] dOmega,
    sigma = -p I + mu (grad v + grad v^T),
    d sigma_ij / dx_j = -dp/dx_i + mu (lap v_i + d(div v)/dx_i),

Lundgaard et al. (2018, eq. 3) with the viscous stress added (the total
stress, as in Abdelhamid & Czekanski). Here ``Psi_e = rho_e``, the element's
physical density, and the integral runs on the current (moved) geometry:

    f_(a i) = sum_e rho_e int_e [sigma_ij dM_a/dx_j + M_a d sigma_ij/dx_j],

``M`` the Q1 (structure) shape functions; the velocity's second derivatives
are those of the Q2 basis on the bilinear element. The load is linear in
``w``: ``f_e = rho_e B_e(Xe) w_e`` with ``B_e`` ``(E, 8, 22)``; its total over
all nodes is the resultant force on the solid (drag, lift), because the
``M_a`` sum to one.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.geometry import physical_gradients, physical_hessians
from tofsi.physics.fluid_kernel import N1, N2, POINTS, WEIGHTS


def load_operator(Xe: np.ndarray, viscosity: float) -> np.ndarray:
    """``B_e`` ``(E, 8, 22)``: element load per unit weight, ``f_e = B_e w_e`` (complex-safe)."""
    E = Xe.shape[0]
    mu = viscosity
    g2, det = physical_gradients(Xe, 2, POINTS)                     # (E, G, 9, 2)
    g1, _ = physical_gradients(Xe, 1, POINTS)                       # (E, G, 4, 2)
    H2 = physical_hessians(Xe, 2, POINTS, g2)                       # (E, G, 9, 2, 2)
    w = det * WEIGHTS                                               # (E, G)
    G = w.shape[1]
    gw = g1 * w[..., None, None]                                    # (E, G, 4, 2)
    Mw = N1[None] * w[..., None]                                    # (E, G, 4)
    # cross[a, k, b, i] = sum_g dM_a/dx_k dN_b/dx_i  (one product over stacked points)
    cross = np.matmul(gw.reshape(E, G, 8).transpose(0, 2, 1), g2.reshape(E, G, 18)).reshape(E, 4, 2, 9, 2)
    dot = cross[:, :, 0, :, 0] + cross[:, :, 1, :, 1]               # grad M_a . grad N_b
    lap = H2[..., 0, 0] + H2[..., 1, 1]                             # (E, G, 9)
    Mlap = np.matmul(Mw.transpose(0, 2, 1), lap)                    # sum_g M_a lap N_b
    MH = np.matmul(Mw.transpose(0, 2, 1), H2.reshape(E, G, 36)).reshape(E, 4, 9, 2, 2)   # [a, b, k, i]
    B = mu * cross.transpose(0, 1, 4, 3, 2) + mu * MH.transpose(0, 1, 4, 2, 3)           # [a, i, b, k]
    B[:, :, 0, :, 0] += mu * (dot + Mlap)
    B[:, :, 1, :, 1] += mu * (dot + Mlap)
    # pressure: -p dM_a/dx_i - M_a dp/dx_i
    P = -(np.matmul(gw.reshape(E, G, 8).transpose(0, 2, 1), N1).reshape(E, 4, 2, 4)
          + np.matmul(Mw.transpose(0, 2, 1), g1.reshape(E, G, 8)).reshape(E, 4, 4, 2).transpose(0, 1, 3, 2))
    out = np.empty((E, 8, 22), dtype=B.dtype)
    out[:, :, :18] = B.reshape(E, 8, 18)
    out[:, :, 18:] = P.reshape(E, 8, 4)
    return out
