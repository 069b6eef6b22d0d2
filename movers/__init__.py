"""Mesh-motion backends, chosen by name.

    >>> import movers
    >>> movers.available()
    ['linear', 'spring', 'yeoh']
    >>> mover = movers.create("yeoh", A20=1e3)

Built-in movers are listed below; third-party packages add theirs through
the entry-point group ``tofsi.movers`` (``name = "package.module:Class"``).
A mover class has a frozen ``Params`` record (validated scene table
``[mover.<name>]``) and is constructed as ``Class(params)``; see
:class:`movers.base.Mover` for the interface.
"""

from __future__ import annotations

from movers.registry import available, create, mover_class, register

__all__ = ["available", "create", "mover_class", "register"]
