"""The fluid element types, chosen by ``fluid.element``: one record each of what depends on it.

* ``"q2q1"`` (default) -- Taylor-Hood: velocity on the 9-node (Q2) quads, pressure on the
  corners; inf-sup stable, no stabilization, Poiseuille flow exact
  (:mod:`tofsi.physics.fluid_kernel`, analytic shape derivatives in
  :mod:`tofsi.physics.fluid_shape`).
* ``"q1q1"`` -- equal order: velocity and pressure on the corners, stabilized by topFlow's
  SUPG/PSPG (:mod:`tofsi.physics.fluid_kernel_q1q1`; shape derivatives by the complex step);
  the element of topFlow (Alexandersen 2023) and TOFLUX, for like-for-like comparisons.

The flow's unknowns are the velocity ``2 k + i`` on the element type's velocity nodes
``k``, then the pressure on the mesh corners. Each record gives the velocity nodes of a
:class:`~tofsi.mesh.structured.StructuredQuadMesh` (element connectivity, coordinates, the nodes
along a side, fine-grid positions for the nested-dissection ordering), the element kernel
with a body force at its quadrature points, its friction partial ``dR_e/dalpha_e``, its
shape derivatives, and the velocity shape functions ``N`` ``(G, k)`` at the kernel's
points (objectives and loads integrate with them), the Q1 shape functions at the velocity
nodes (``to_corners``: the fluid load tests the velocity rows with them) and, where
written, analytic shape derivatives of the fluid load's operators and of the dissipation.
"""

from __future__ import annotations

import numpy as np

from tofsi.fem.complex_step import corner_derivatives
from tofsi.fem.geometry import physical_gradients
from tofsi.fem.shapes import Q1_NODES, Q2_NODES, shape_functions
from tofsi.physics import fluid_kernel, fluid_kernel_q1q1
from tofsi.physics.fluid_shape import dissipation_shape, fluid_shape, mass_shape, stress_load_shape


class FluidElement:
    """What both element types share: the velocity fields at the kernel's points."""

    degree: int
    POINTS: np.ndarray
    WEIGHTS: np.ndarray
    N: np.ndarray

    @classmethod
    def velocity_fields(cls, Xe, ve):
        """Basis gradients ``(E, G, k, 2)``, weights ``w det J`` ``(E, G)``, ``v`` ``(E, G, 2)`` and
        ``grad v`` ``(E, G, 2, 2)`` (``L_ij = dv_i/dx_j``) of element velocities ``ve`` ``(E, k, 2)``."""
        grad, det = physical_gradients(Xe, cls.degree, cls.POINTS)
        v = np.matmul(cls.N, ve)
        L = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)
        return grad, det * cls.WEIGHTS, v, L


class TaylorHood(FluidElement):
    """Q2/Q1 (the default)."""

    name = "q2q1"
    degree = 2
    nodes_per_element = 9
    POINTS, WEIGHTS = fluid_kernel.POINTS, fluid_kernel.WEIGHTS
    N = fluid_kernel.N2                                            # (G, 9)
    to_corners, _ = shape_functions(1, Q2_NODES)                   # (9, 4): M_a at the velocity nodes
    # analytic shape derivatives of the fluid load's operators and of the dissipation functional
    # (None: the complex step)
    mass_shape = staticmethod(mass_shape)
    stress_load_shape = staticmethod(stress_load_shape)
    dissipation_shape = staticmethod(dissipation_shape)

    # ---- velocity nodes of a structured mesh --------------------------------------------
    @staticmethod
    def quads(mesh) -> np.ndarray:
        return mesh.quads9

    @staticmethod
    def n_nodes(mesh) -> int:
        return mesh.n_nodes9

    @staticmethod
    def points(mesh, corners=None) -> np.ndarray:
        """Velocity node coordinates ``(k, 2)`` of the mesh with corner positions ``corners``."""
        return mesh.points9(corners)

    @staticmethod
    def side_nodes(mesh, side: str) -> np.ndarray:
        """Velocity nodes along a side, in order (corner, mid-side, corner, ...)."""
        return mesh.side_nodes9(side)

    @staticmethod
    def grid_positions(mesh) -> np.ndarray:
        """Fine-grid positions ``(k, 2)`` of the velocity nodes (corners at even positions)."""
        I, J = np.meshgrid(np.arange(2 * mesh.nx + 1), np.arange(2 * mesh.ny + 1), indexing="xy")
        pos = np.empty((mesh.n_nodes9, 2), dtype=np.int64)
        pos[mesh.node9(I.ravel(), J.ravel())] = np.column_stack([I.ravel(), J.ravel()])
        return pos

    # ---- kernels --------------------------------------------------------------------------
    @classmethod
    def residual(cls, Xe, ve, pe, alpha, density, viscosity, symmetric, force=None, jacobian=True):
        """``(R_e (E, 22), K_e (E, 22, 22) or None)``; ``force`` (E, G, 2) [N/m^3] at the points."""
        Re, Ke = fluid_kernel.fluid_elements(Xe, ve, pe, alpha, density, viscosity, symmetric, jacobian)
        if force is not None:
            _, det = physical_gradients(Xe, 1, cls.POINTS)
            Re = Re.astype(np.result_type(Re, force))
            Re[:, :18] -= np.matmul(cls.N.T, force * (det * cls.WEIGHTS)[..., None]).reshape(len(Xe), 18)
        return Re, Ke

    @staticmethod
    def alpha_partial(Xe, ve, pe, alpha, density, viscosity, symmetric, force=None) -> np.ndarray:
        """``dR_e/dalpha_e`` ``(E, 22)``: ``int N_a v_i`` on the velocity rows."""
        return fluid_kernel.brinkman_partial(Xe, ve)

    @classmethod
    def shape(cls, Xe, ve, pe, alpha, density, viscosity, symmetric, force_at=None):
        """``(R_e, dR_e/dXe (E, 22, 8))``: analytic, or by the complex step with a body force
        ``force_at(Xe) -> (E, G, 2)``."""
        if force_at is None:
            return fluid_shape(Xe, ve, pe, alpha, density, viscosity, symmetric)

        def residual(Xc):
            return cls.residual(Xc, ve, pe, alpha, density, viscosity, symmetric, force_at(Xc), False)[0]
        return residual(Xe), corner_derivatives(residual, Xe)


class EqualOrder(FluidElement):
    """Stabilized Q1/Q1 (topFlow's and TOFLUX's element)."""

    name = "q1q1"
    degree = 1
    nodes_per_element = 4
    POINTS, WEIGHTS = fluid_kernel_q1q1.POINTS, fluid_kernel_q1q1.WEIGHTS
    N = fluid_kernel_q1q1.N1                                       # (G, 4)
    to_corners, _ = shape_functions(1, Q1_NODES)                   # (4, 4): the identity
    mass_shape = stress_load_shape = dissipation_shape = None

    @staticmethod
    def quads(mesh) -> np.ndarray:
        return mesh.quads

    @staticmethod
    def n_nodes(mesh) -> int:
        return mesh.n_nodes

    @staticmethod
    def points(mesh, corners=None) -> np.ndarray:
        return mesh.points if corners is None else corners

    @staticmethod
    def side_nodes(mesh, side: str) -> np.ndarray:
        return mesh.side_nodes(side)

    @staticmethod
    def grid_positions(mesh) -> np.ndarray:
        return mesh.grid_positions()

    @staticmethod
    def residual(Xe, ve, pe, alpha, density, viscosity, symmetric, force=None, jacobian=True):
        """``(R_e (E, 12), K_e (E, 12, 12) or None)``; ``force`` (E, G, 2) [N/m^3] at the points."""
        return fluid_kernel_q1q1.element_residual(Xe, ve, pe, alpha, density, viscosity, symmetric, force,
                                                  jacobian)

    @staticmethod
    def alpha_partial(Xe, ve, pe, alpha, density, viscosity, symmetric, force=None) -> np.ndarray:
        """``dR_e/dalpha_e`` ``(E, 12)``, the stabilization's friction and ``tau``'s included."""
        return fluid_kernel_q1q1.alpha_partial(Xe, ve, pe, alpha, density, viscosity, symmetric, force)

    @staticmethod
    def shape(Xe, ve, pe, alpha, density, viscosity, symmetric, force_at=None):
        """``(R_e, dR_e/dXe (E, 12, 8))`` by the complex step."""
        return fluid_kernel_q1q1.shape_derivatives(Xe, ve, pe, alpha, density, viscosity, symmetric, force_at)


ELEMENTS = {cls.name: cls for cls in (TaylorHood, EqualOrder)}
