"""Taylor-Hood Q2/Q1 element kernel: steady Navier-Stokes with Brinkman friction.

Element unknowns: velocity at the 9 Q2 nodes, node-interleaved
``[v0x, v0y, ..., v8x, v8y]`` (18), then pressure at the 4 corners (4).
Residual on the element's current geometry (corners ``Xe``), 3x3 Gauss points:

    R_v[a, i] = int rho_f (v . grad v_i) N_a + T_ij dN_a/dx_j + alpha v_i N_a
    R_p[c]    = -int M_c div v

with ``T = mu grad v - p I`` (gradient form; natural outlet condition
``mu dv/dn - p n = 0``) or ``T = mu (grad v + grad v^T) - p I`` (symmetric
form; natural condition ``sigma n = 0``). ``N`` are the Q2 and ``M`` the Q1
shape functions. The Jacobian is the exact derivative (Newton), with the
convection linearized as ``rho_f [(v . grad dv) + (dv . grad) v]``. Stokes
flow is ``rho_f = 0``.

All inputs may be complex, so shape derivatives (with respect to ``Xe``)
come from the same code by the complex step.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.geometry import physical_gradients
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions

POINTS, WEIGHTS = gauss_square(3)
N2, _ = shape_functions(2, POINTS)            # (G, 9)
N1, _ = shape_functions(1, POINTS)            # (G, 4)


def velocity_fields(Xe, ve):
    """Gradients of the basis (E, G, 9, 2), weights ``w det J`` (E, G), v (E, G, 2), grad v (E, G, 2, 2)."""
    grad, det = physical_gradients(Xe, 2, POINTS)
    w = det * WEIGHTS
    v = np.matmul(N2, ve)                                        # (E, G, 2)
    L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)          # L_ij = dv_i/dx_j (E, G, 2, 2)
    return grad, w, v, L


def fluid_element(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False,
                  jacobian: bool = True):
    """Element residuals ``(E, 22)`` and Jacobians ``(E, 22, 22)`` (or None).

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


def brinkman_partial(Xe, ve):
    """``dR/dalpha`` per element ``(E, 22)``: ``int v_i N_a`` on the velocity rows."""
    E = Xe.shape[0]
    _, det = physical_gradients(Xe, 1, POINTS)
    v = np.matmul(N2, ve)
    out = np.zeros((E, 22), dtype=np.result_type(Xe, ve))
    out[:, :18] = np.matmul(N2.T, v * (det * WEIGHTS)[..., None]).reshape(E, 18)
    return out


CHUNK = 4096          # elements per kernel call in :func:`fluid_elements` (bounds the temporaries)


def fluid_elements(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False,
                   jacobian: bool = True, chunk: int = CHUNK):
    """:func:`fluid_element` over chunks of ``chunk`` elements into preallocated ``(E, 22)`` and
    ``(E, 22, 22)`` arrays: the same values (each element's arithmetic is its own), with the
    kernel's temporaries -- about 14 kB per element, 3.5x the Jacobians themselves -- held
    for one chunk only."""
    E = Xe.shape[0]
    if E <= chunk:
        return fluid_element(Xe, ve, pe, alpha, density, viscosity, symmetric, jacobian)
    dtype = np.result_type(Xe, ve, pe, alpha, float)
    Re = np.empty((E, 22), dtype=dtype)
    Ke = np.empty((E, 22, 22), dtype=dtype) if jacobian else None
    for a in range(0, E, chunk):
        b = min(a + chunk, E)
        r, k = fluid_element(Xe[a:b], ve[a:b], pe[a:b], alpha[a:b], density, viscosity, symmetric, jacobian)
        Re[a:b] = r
        if jacobian:
            Ke[a:b] = k
    return Re, Ke
