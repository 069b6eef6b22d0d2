"""The weight of the solid phase: a dead load on the structure (``structure.density``,
``structure.gravity``).

Per unit volume of solid the body force is ``rho_s g`` [N/m^3] (``rho_s`` the
solid's density [kg/m^3], ``g = (gx, gy)`` [m/s^2]); on Q1 nodes of the
reference mesh (total Lagrangian: a dead load, independent of ``u`` and of the
fluid mesh ``x``)::

    f_(a i) = sum_e psi(rho_e) rho_s g_i int_e N_a dX,      psi = rho^k,

weighted by the solid phase like the fluid load (``k`` =
``structure.load_exponent``: 1 is the physical mass of a gray element, ``k = p``
keeps a gray element's displacement bounded as it empties, as for the fluid
load; with 0/1 densities both are the solid's weight). Its design derivative
is ``df_e/drho_e = psi'(rho_e) rho_s g int_e N_a dX``.
"""

from __future__ import annotations

import numpy as np

from tofsi.core.blocks import Continuation
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.geometry import jacobians
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions


def shape_integrals(Xe: np.ndarray) -> np.ndarray:
    """``int_e N_a dX`` ``(E, 4)`` [m^2] of quads with corners ``Xe`` ``(E, 4, 2)`` (2x2 Gauss points:
    exact on the bilinear map)."""
    points, weights = gauss_square(2)
    N, _ = shape_functions(1, points)                       # (G, 4)
    _, det, _ = jacobians(Xe, points)                       # (E, G)
    return (det * weights) @ N


def weight(rho, params: Continuation | None) -> np.ndarray:
    """``psi = rho^k`` per element (``k`` the load exponent of ``params``)."""
    k = (params or Continuation()).load_exponent
    return np.asarray(rho, dtype=float) ** k


def weight_derivative(rho, params: Continuation | None) -> np.ndarray:
    """``psi'(rho) = k rho^(k - 1)``."""
    k = (params or Continuation()).load_exponent
    return k * np.asarray(rho, dtype=float) ** (k - 1.0)


class DeadLoad:
    """The solid phase's weight on a mesh: ``density`` ``rho_s`` [kg/m^3], ``gravity`` ``(gx, gy)`` [m/s^2]."""

    def __init__(self, mesh, density: float, gravity):
        self.size = 2 * mesh.n_nodes
        self.dofs = element_dofs(mesh.quads, 2)
        g = np.asarray(gravity, dtype=float)
        # rho_s g_i int_e N_a dX per element, node-interleaved (E, 8) [N/m]
        self.full = (density * shape_integrals(mesh.points[mesh.quads])[:, :, None] * g).reshape(-1, 8)

    def elements(self, rho, params: Continuation | None = None) -> np.ndarray:
        """Element loads ``psi(rho_e) rho_s g int_e N_a`` ``(E, 8)`` [N/m]."""
        return self.full * weight(rho, params)[:, None]

    def load(self, rho, params: Continuation | None = None) -> np.ndarray:
        """Nodal load (2n,) [N/m]."""
        return assemble_vector(self.dofs, self.elements(rho, params), self.size)

    def density_vectors(self, rho, params: Continuation | None = None) -> np.ndarray:
        """``df_e/drho_e`` ``(E, 8)``."""
        return self.full * weight_derivative(rho, params)[:, None]

    def resultant(self, rho, params: Continuation | None = None) -> tuple[float, float]:
        """The total weight ``(Fx, Fy)`` [N/m]."""
        fe = self.elements(rho, params)
        return float(fe[:, 0::2].sum()), float(fe[:, 1::2].sum())
