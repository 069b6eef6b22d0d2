"""The flow at one state on a set of elements, as objectives read it: one record for the whole
mesh (:meth:`tofsi.physics.flow.Flow.view`) and for a rank's slab
(:meth:`tofsi.parallel.flow_system.DistributedFlow.view`).

A :class:`FlowView` holds the elements' corners on the configuration the flow was
solved on, their dof values, where those dofs go (``dofs`` into a vector of ``size``:
the flow's unknowns, or a slab's ghosted ones), the densities and the frozen
coefficients of the stage (:class:`FlowCoefficients`), and the element basis where
the flow keeps it per configuration (:attr:`~tofsi.physics.fluid_elements.FluidElement.keeps_basis`).
The element velocities at the kernel's points are formed once per view
(:attr:`FlowView.fields`), so an objective's value and partials share them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from tofsi.physics.interpolation import Brinkman


@dataclass(frozen=True, eq=False)
class FlowCoefficients:
    """The frozen coefficients of the flow's element kernels at one stage and design.

    alpha : Brinkman friction per element ``(E,)`` [kg/(m^3 s)]; brinkman : the interpolation
    ``alpha(rho)`` at the stage's ``q`` (its derivative for ``d/drho``); density [kg/m^3] (0:
    Stokes); viscosity [Pa s]; symmetric : the strain-rate viscous form (else the gradient form).
    """

    alpha: np.ndarray
    brinkman: Brinkman
    density: float
    viscosity: float
    symmetric: bool


@dataclass(frozen=True, eq=False)
class FlowView:
    """The flow on ``E`` elements at one state.

    element : the fluid element type (:mod:`tofsi.physics.fluid_elements`); Xe : corners
    ``(E, 4, 2)`` [m] on the configuration; we : element dof values ``(E, m)`` (velocity
    ``2 k``, then pressure 4); dofs : where they go ``(E, m)``, into a vector of ``size``
    (what an objective's ``df/dw`` is assembled into); rho : densities ``(E,)``;
    coefficients : :class:`FlowCoefficients`; basis : the element basis of ``Xe`` the flow keeps
    (None: formed by the view when first read).
    """

    element: type
    Xe: np.ndarray
    we: np.ndarray
    dofs: np.ndarray
    size: int
    rho: np.ndarray
    coefficients: FlowCoefficients
    basis: tuple | None = None

    @property
    def ve(self) -> np.ndarray:
        """Element velocities at the velocity nodes ``(E, k, 2)`` [m/s]."""
        k2 = 2 * self.element.nodes_per_element
        return self.we[:, :k2].reshape(len(self.we), -1, 2)

    @property
    def pe(self) -> np.ndarray:
        """Element pressures at the corners ``(E, 4)`` [Pa]."""
        return self.we[:, 2 * self.element.nodes_per_element:]

    @cached_property
    def fields(self):
        """``(grad N (E, G, k, 2), w det J (E, G), v (E, G, 2), grad v (E, G, 2, 2))`` at the
        kernel's points: the basis and the element velocities, formed once per view."""
        return self.element.velocity_fields(self.Xe, self.ve, self.basis)

    def at(self, Xc: np.ndarray) -> "FlowView":
        """The same state on corners ``Xc`` ``(E, 4, 2)`` (complex for the complex step): its
        basis formed anew."""
        return replace(self, Xe=Xc, basis=None)
