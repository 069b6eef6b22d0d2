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
    """``B_e`` ``(E, 8, 22)``: element load per unit density, ``f_e = B_e w_e`` (complex-safe)."""
    E = Xe.shape[0]
    mu = viscosity
    g2, det = physical_gradients(Xe, 2, POINTS)                     # (E, G, 9, 2)
    g1, _ = physical_gradients(Xe, 1, POINTS)                       # (E, G, 4, 2)
    H2 = physical_hessians(Xe, 2, POINTS, g2)                       # (E, G, 9, 2, 2)
    w = det * WEIGHTS                                               # (E, G)
    B = np.zeros((E, 4, 2, 9, 2), dtype=np.result_type(Xe, float))
    # mu [delta_ik grad M_a . grad N_b + dM_a/dx_k dN_b/dx_i]
    gw = g1 * w[..., None, None]
    dot = np.einsum("egaj,egbj->eab", gw, g2)
    cross = np.einsum("egak,egbi->eaibk", gw, g2)
    B += mu * cross
    B[:, :, 0, :, 0] += mu * dot
    B[:, :, 1, :, 1] += mu * dot
    # mu M_a [delta_ik lap N_b + d2N_b/dx_k dx_i]
    Mw = N1[None] * w[..., None]                                    # (E, G, 4)
    lap = H2[..., 0, 0] + H2[..., 1, 1]                             # (E, G, 9)
    B[:, :, 0, :, 0] += mu * np.einsum("ega,egb->eab", Mw, lap)
    B[:, :, 1, :, 1] += mu * np.einsum("ega,egb->eab", Mw, lap)
    B += mu * np.einsum("ega,egbki->eaibk", Mw, H2)
    # pressure: -p dM_a/dx_i - M_a dp/dx_i
    P = -(np.einsum("egai,gc->eaic", gw, N1) + np.einsum("ega,egci->eaic", Mw, g1))
    out = np.empty((E, 8, 22), dtype=B.dtype)
    out[:, :, :18] = B.reshape(E, 8, 18)
    out[:, :, 18:] = P.reshape(E, 8, 4)
    return out
