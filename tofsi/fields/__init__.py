"""The fields of the coupled problem, one module each, registered in :data:`tofsi.core.registry.FIELDS`.

* :mod:`tofsi.fields.flow` -- ``w``, the flow (table ``[fluid]``);
* :mod:`tofsi.fields.structure` -- ``u``, the structure (table ``[structure]``);
* :mod:`tofsi.fields.motion` -- ``x``, the fluid mesh's motion (table ``[mover]``).

Each module holds its settings record and scene table, its block and
linearization and its :class:`~tofsi.fields.base.Field` entry (what an entry
carries: :mod:`tofsi.fields.base`); its physics is imported when the field is
built, so loading a scene imports none. This package is the registry's home:
importing it registers the built-in fields, in dependency order (the structure
is loaded by the flow, the mesh follows the structure).
"""

from tofsi.fields import flow, structure, motion  # noqa: F401  (registered in this order)
