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
NN2 = (N2[:, :, None] * N2[:, None, :]).reshape(len(POINTS), 81)      # N_a N_b at the points (G, 81)
# CONVECTION[(g, i, j), (a, i', b, j')] = N_a N_b (g) delta_ii' delta_jj': maps w L_ij at the points
# to the velocity block rho int N_a N_b L_ij laid out as the element matrix's rows and columns
CONVECTION = np.einsum("gab,ik,jl->gijakbl", NN2.reshape(-1, 9, 9), np.eye(2), np.eye(2)).reshape(-1, 324)


def velocity_fields(Xe, ve):
    """Gradients of the basis (E, G, 9, 2), weights ``w det J`` (E, G), v (E, G, 2), grad v (E, G, 2, 2)."""
    grad, det = physical_gradients(Xe, 2, POINTS)
    w = det * WEIGHTS
    v = np.matmul(N2, ve)                                        # (E, G, 2)
    L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)          # L_ij = dv_i/dx_j (E, G, 2, 2)
    return grad, w, v, L


def fluid_element(Xe, ve, pe, alpha, density: float, viscosity: float, symmetric: bool = False,
                  jacobian: bool = True, out=None):
    """Element residuals ``(E, 22)`` and Jacobians ``(E, 22, 22)`` (or None), written into
    ``out = (Re, Ke)`` when given.

    Xe (E, 4, 2) corners [m]; ve (E, 9, 2) [m/s]; pe (E, 4) [Pa]; alpha (E,) [kg/(m^3 s)].
    The velocity block is built in the element matrix's own layout ``[a, i, b, j]``: the
    terms on the component diagonal (viscous ``mu int grad N_a . grad N_b``, friction
    ``alpha int N_a N_b``, convection ``rho int N_a v . grad N_b``) per element, the
    convection's ``rho int N_a N_b L_ij`` for all elements by one matrix product with
    :data:`CONVECTION`.
    """
    E = Xe.shape[0]
    mu = viscosity
    grad, w, v, L = velocity_fields(Xe, ve)
    G = w.shape[1]
    p = np.matmul(pe, N1.T)                                      # (E, G)
    div = L[..., 0, 0] + L[..., 1, 1]
    source = density * np.matmul(L, v[..., None])[..., 0] + alpha[:, None, None] * v   # (E, G, 2)
    T = mu * (L + np.swapaxes(L, -1, -2) if symmetric else L)
    T[..., 0, 0] -= p
    T[..., 1, 1] -= p
    gw = grad * w[..., None, None]                               # (E, G, 9, 2)
    gws = gw.transpose(0, 2, 1, 3).reshape(E, 9, 2 * G)          # [e, a, (g, j)]
    Rv = np.matmul(N2.T, source * w[..., None])                  # (E, 9, 2)
    Rv += np.matmul(gws, T.transpose(0, 1, 3, 2).reshape(E, 2 * G, 2))   # sum_g,j w dN_a/dx_j T_ij
    Rp = -np.matmul(div * w, N1)                                 # (E, 4)
    Re = np.empty((E, 22), dtype=Rv.dtype) if out is None else out[0]
    Re[:, :18] = Rv.reshape(E, 18)
    Re[:, 18:] = Rp
    if not jacobian:
        return Re, None

    Ke = np.empty((E, 22, 22), dtype=Re.dtype) if out is None else out[1]
    gs = grad.transpose(0, 2, 1, 3).reshape(E, 9, 2 * G)         # [e, b, (g, j)]
    diag = mu * np.matmul(gws, gs.transpose(0, 2, 1))            # mu int grad N_a . grad N_b
    diag += (alpha[:, None] * np.matmul(w, NN2)).reshape(E, 9, 9)   # alpha int N_a N_b
    if density:
        Nw = N2.T[None] * w[:, None, :]                          # (E, 9, G)
        vgrad = np.matmul(grad, v[..., None])[..., 0]            # v . grad N_b (E, G, 9)
        diag += density * np.matmul(Nw, vgrad)
        # (dv . grad) v: rho int N_a N_b L_ij, one product with the points' N_a N_b
        wL = ((density * w)[..., None] * L.reshape(E, G, 4)).reshape(E, 4 * G)
        vv = (wL @ CONVECTION).reshape(E, 9, 2, 9, 2)             # [e, a, i, b, j]
    else:
        vv = np.zeros((E, 9, 2, 9, 2), dtype=Re.dtype)
    if symmetric:                                                # mu int dN_a/dx_j dN_b/dx_i
        M = np.matmul(gw.reshape(E, G, 18).transpose(0, 2, 1), grad.reshape(E, G, 18)).reshape(E, 9, 2, 9, 2)
        vv += mu * M.transpose(0, 1, 4, 3, 2)
    vv[:, :, 0, :, 0] += diag
    vv[:, :, 1, :, 1] += diag
    Ke[:, :18, :18] = vv.reshape(E, 18, 18)
    Kvp = -np.matmul(gw.reshape(E, G, 18).transpose(0, 2, 1), N1)   # (E, 18, 4): -int dN_a/dx_i M_c
    Ke[:, :18, 18:] = Kvp
    Ke[:, 18:, :18] = Kvp.transpose(0, 2, 1)
    Ke[:, 18:, 18:] = 0.0
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
    """:func:`fluid_element` over chunks of ``chunk`` elements, each written into its slice of
    preallocated ``(E, 22)`` and ``(E, 22, 22)`` arrays: the same values (each element's
    arithmetic is its own), with the
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
        fluid_element(Xe[a:b], ve[a:b], pe[a:b], alpha[a:b], density, viscosity, symmetric, jacobian,
                      out=(Re[a:b], Ke[a:b] if jacobian else None))
    return Re, Ke
