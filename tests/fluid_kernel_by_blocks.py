"""The Taylor-Hood element kernel as first written: the oracle of the element-layout kernel.

Each coupling block of the velocity Jacobian is formed in its own layout and
added into its strided slice of ``K_e`` (the viscous-Brinkman diagonal, the
four convection blocks ``rho int N_a N_b L_ij``); the library's kernel builds
the velocity block in the element matrix's layout by one product instead.
The two share the basis evaluation (``velocity_fields``) only.
"""

import numpy as np

from tofsi.physics.fluid_kernel import N1, N2, velocity_fields


def fluid_element_by_blocks(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False,
                  jacobian: bool = True):
    """The Taylor-Hood kernel as first written (each coupling block added into its strided
    slice of ``K_e``): the oracle of the element-layout kernel. Element residuals ``(E, 22)``
    and Jacobians ``(E, 22, 22)`` (or None).

    Xe (E, 4, 2) corners [m]; ve (E, 9, 2) [m/s]; pe (E, 4) [Pa]; alpha (E,) [kg/(m^3 s)].
    """
    E = Xe.shape[0]
    mu = viscosity
    grad, w, v, L = velocity_fields(Xe, ve)
    p = np.matmul(pe, N1.T)                                      # (E, G)
    div = L[..., 0, 0] + L[..., 1, 1]
    source = density * np.matmul(L, v[..., None])[..., 0] + alpha[:, None, None] * v   # (E, G, 2)
    T = mu * (L + np.swapaxes(L, -1, -2) if symmetric else L)
    T = T - p[..., None, None] * np.eye(2)
    Rv = np.matmul(N2.T, source * w[..., None])                  # (E, 9, 2)
    Rv = Rv + (np.matmul(grad, np.swapaxes(T, -1, -2)) * w[..., None, None]).sum(axis=1)
    Rp = -np.matmul(div * w, N1)                                 # (E, 4)
    Re = np.concatenate([Rv.reshape(E, 18), Rp], axis=1)
    if not jacobian:
        return Re, None

    G = w.shape[1]
    Ke = np.zeros((E, 22, 22), dtype=Re.dtype)
    gw = grad * w[..., None, None]                               # (E, G, 9, 2)
    if symmetric:                                                # all gradient pairs
        g18 = grad.reshape(E, G, 18)
        M = np.matmul(gw.reshape(E, G, 18).transpose(0, 2, 1), g18).reshape(E, 9, 2, 9, 2)
        lap = M[:, :, 0, :, 0] + M[:, :, 1, :, 1]
        for i in range(2):                                       # mu dN_a/dx_j dN_b/dx_i
            for j in range(2):
                Ke[:, i:18:2, j:18:2] += mu * M[:, :, j, :, i]
    else:                                                        # int grad N_a . grad N_b only
        stacked = grad.transpose(0, 2, 1, 3).reshape(E, 9, 2 * G)
        lap = np.matmul(gw.transpose(0, 2, 1, 3).reshape(E, 9, 2 * G), stacked.transpose(0, 2, 1))
    Nw = N2.T[None] * w[:, None, :]                              # (E, 9, G)
    diag = mu * lap + alpha[:, None, None] * np.matmul(Nw, N2)   # viscous + Brinkman
    if density:
        vgrad = np.matmul(grad, v[..., None])[..., 0]            # v . grad N_b (E, G, 9)
        diag = diag + density * np.matmul(Nw, vgrad)
        # (dv . grad) v: rho int N_a L_ij N_b for all (i, j) in one product
        NL = (Nw[..., None] * L.reshape(E, 1, G, 4)).transpose(0, 1, 3, 2).reshape(E, 36, G)
        conv = (density * np.matmul(NL, N2)).reshape(E, 9, 2, 2, 9)
        for i in range(2):
            for j in range(2):
                Ke[:, i:18:2, j:18:2] += conv[:, :, i, j, :]
    Ke[:, 0:18:2, 0:18:2] += diag
    Ke[:, 1:18:2, 1:18:2] += diag
    Kvp = -np.matmul(gw.reshape(E, G, 18).transpose(0, 2, 1), N1)   # (E, 18, 4): -int dN_a/dx_i M_c
    Ke[:, :18, 18:] = Kvp
    Ke[:, 18:, :18] = Kvp.transpose(0, 2, 1)
    return Re, Ke
