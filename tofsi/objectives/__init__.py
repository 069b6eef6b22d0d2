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

from tofsi.core.registry import OBJECTIVES


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


for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["OBJECTIVES", "Objective"]
