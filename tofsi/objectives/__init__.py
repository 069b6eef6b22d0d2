"""Objectives of a coupled state: one module each, registered in :data:`tofsi.core.registry.OBJECTIVES`.

An objective is one class, in one module of this package (or of a plugin,
through the entry-point group ``tofsi.objectives``), that carries its whole
story -- the scene key ``design.objective`` reads its ``name``, the scene check
its ``needs`` (the field it is a figure of), the pictures its ``label`` and
``units``, and the table ``[objective.<name>]`` its parameter record ``Params``
(a frozen record of :func:`tofsi.core.config.option` fields; the instance's
``params``)::

    @OBJECTIVES.register
    class Compliance(Objective):
        name, needs, label, units = "compliance", "u", "compliance", "J/m"
        def value(self, model, state) -> float: ...
        def partials(self, model, state) -> dict: ...

Every module of this package is imported when the registry is first read,
so adding an objective is adding its file. Partials are keyed by field name,
``{"u": dq/du, "x": dq/dx, "w": dq/dw, "rho": dq/drho}`` (missing keys are
zero), for the adjoint; continuation parameters (the Brinkman q, the load
exponent) are the state's (``state.params``).
"""

from __future__ import annotations

import importlib
import pkgutil

import numpy as np

from tofsi.core.registry import OBJECTIVES
from tofsi.fem.assembly import assemble_vector, element_dofs
from tofsi.fem.complex_step import corner_derivatives


class Objective:
    """A quantity a design minimizes.

    name : the value of ``design.objective``; needs : the field it is a figure of (``"w"``
    the flow, ``"u"`` the structure, ...: the scene must solve it); label, units : how
    pictures and summaries name it; Params : its parameter record (``[objective.<name>]``),
    None for an objective without parameters; params : the instance's record.
    """

    name: str
    needs: str
    label: str
    units: str
    Params: type | None = None

    def __init__(self, params=None):
        if self.Params is not None and params is None:
            params = self.Params()
        self.params = params

    @classmethod
    def axis_label(cls) -> str:
        """``"compliance [J/m]"``."""
        return f"{cls.label} [{cls.units}]"

    def value(self, model, state) -> float:
        raise NotImplementedError

    def partials(self, model, state) -> dict:
        raise NotImplementedError


class FlowObjective(Objective):
    """An objective summed over the flow's elements and read from the flow's view alone
    (:class:`~tofsi.physics.flow_view.FlowView`: corners, dof values, densities, frozen
    coefficients, the basis and element velocities): write ``element_values(view)`` ``(E,)``
    and ``element_partials(view) -> (df_e/dw_e (E, m), df_e/drho_e (E,))``; :meth:`value`,
    :meth:`partials` (the shape partial by the complex step through ``element_values``, or
    :meth:`shape_elements`) follow, and the distributed flow differentiates it by slabs
    (:class:`tofsi.parallel.flow_adjoint.SlabObjective`) with the same two methods."""

    needs = "w"

    def element_values(self, view) -> np.ndarray:
        raise NotImplementedError

    def element_partials(self, view) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def shape_elements(self, view) -> np.ndarray:
        """``df_e/dXe`` ``(E, 8)`` (corner ``k``, coordinate ``m`` at ``2 k + m``): the complex step."""
        return corner_derivatives(lambda Xc: self.element_values(view.at(Xc)), view.Xe)

    @staticmethod
    def view(model, state):
        return model.flow.view(state.w, state.mesh_displacement, state.rho, state.params)

    def value(self, model, state) -> float:
        return float(self.element_values(self.view(model, state)).sum())

    def partials(self, model, state) -> dict:
        view = self.view(model, state)
        dw, drho = self.element_partials(view)
        out = {"w": assemble_vector(view.dofs, dw, view.size), "rho": drho}
        if state.x is not None:                       # the flow saw the moved mesh
            mesh = model.mesh
            out["x"] = assemble_vector(element_dofs(mesh.quads, 2), self.shape_elements(view), 2 * mesh.n_nodes)
        return out


for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["OBJECTIVES", "FlowObjective", "Objective"]
