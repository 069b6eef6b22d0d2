"""The flow Jacobian's block preconditioner from the flow's element data (the iterative path).

:class:`tofsi.linalg.iterative.BlockSaddlePreconditioner` needs the two
parts of its Schur complement approximation, which come from the mesh and
the Brinkman friction, not from the assembled Jacobian:

* ``M_mu`` -- the lumped Q1 pressure mass over the viscosity,
  ``sum_e |e| / (4 mu)`` at each corner [m^2 / (Pa s)];
* ``(alpha M_v)^{-1}`` -- the inverse of the lumped Q2 velocity mass weighted
  by the element's friction, ``1 / sum_e alpha_e |e| / 9`` per velocity dof,
  with ``alpha_e`` floored at ``FLOOR mu / |e|`` (so fluid elements, where
  ``alpha`` may be 0, make ``L_alpha`` stiff and its inverse negligible);
  zero on Dirichlet dofs.

Both are evaluated on the mesh moved by ``x`` with the densities ``rho``.
"""

from __future__ import annotations

import numpy as np

from tofsi.linalg.iterative import FLOOR, TRANSPOSE_TOL, BlockSaddlePreconditioner


def element_areas(corners: np.ndarray) -> np.ndarray:
    """Areas ``(E,)`` [m^2] of quadrilaterals with corners ``(E, 4, 2)`` (counter-clockwise)."""
    d1 = corners[:, 2] - corners[:, 0]
    d2 = corners[:, 3] - corners[:, 1]
    return 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def schur_parts(flow, x=None, rho=None, params=None) -> tuple[np.ndarray, np.ndarray]:
    """``(M_mu (n_p,), 1/(alpha M_v) (n_v,))`` of the flow on the mesh moved by ``x``."""
    mesh, mu = flow.mesh, flow.settings.viscosity
    area = element_areas(flow.corners(x))                                          # (E,)
    n_p = flow.size - flow.n_velocity
    mass = np.bincount(mesh.quads.ravel(), np.repeat(area / (4 * mu), 4), minlength=n_p)   # (n_p,)
    alpha = np.maximum(flow.alpha(rho, params), FLOOR * mu / area)                  # (E,)
    friction = np.bincount(mesh.quads9.ravel(), np.repeat(alpha * area / 9, 9),
                           minlength=mesh.n_nodes9)                                # (n9,)
    weights = np.repeat(1.0 / friction, 2)                                         # (n_v,)
    weights[flow.bc.is_fixed[:flow.n_velocity]] = 0.0
    return mass, weights


def flow_preconditioner(flow, A, x=None, rho=None, params=None, pressure_solver: str = "amg",
                        tol: float = 1e-10, transpose_tol: float = TRANSPOSE_TOL) -> BlockSaddlePreconditioner:
    """The block preconditioner (and GMRES) of the constrained flow Jacobian ``A`` at ``(x, rho)``
    (``transpose_tol``: the adjoint's transposed solves, ``solver.adjoint_tol``)."""
    mass, weights = schur_parts(flow, x, rho, params)
    return BlockSaddlePreconditioner(A, flow.n_velocity, mass, weights, flow.bc.is_fixed,
                                     pressure_solver=pressure_solver, tol=tol, transpose_tol=transpose_tol)
