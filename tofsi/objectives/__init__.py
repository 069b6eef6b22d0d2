"""Objectives of a coupled state: one module each, registered in :data:`tofsi.core.registry.OBJECTIVES`.

An objective is one class, in one module of this package, that carries its
whole story -- the scene key ``design.objective`` reads its ``name``, the
scene check its ``needs``, the pictures its ``label`` and ``units``::

    @OBJECTIVES.register
    class Compliance(Objective):
        name, needs, label, units = "compliance", "structure", "compliance", "J/m"
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

from tofsi.core.registry import OBJECTIVES


class Objective:
    """A quantity a design minimizes.

    name : the value of ``design.objective``; needs : the effect it is a figure of
    (``"fluid"`` or ``"structure"``: ``effects.<needs>`` must be on); label, units :
    how pictures and summaries name it.
    """

    name: str
    needs: str
    label: str
    units: str

    @classmethod
    def axis_label(cls) -> str:
        """``"compliance [J/m]"``."""
        return f"{cls.label} [{cls.units}]"

    def value(self, model, state) -> float:
        raise NotImplementedError

    def partials(self, model, state) -> dict:
        raise NotImplementedError


for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["OBJECTIVES", "Objective"]
