"""Adjoint sensitivities over field blocks: the block adjoint solve and gradient checks.

    from adjoint import Adjoint
    adj = Adjoint(system, state)           # a BlockSystem and a converged state of it
    df_drho = adj.gradient(partials)       # partials {field: df/dz, "rho": df/drho}

The package knows blocks (:mod:`tofsi.core.blocks`), not physics.
"""

from adjoint.solve import Adjoint

__all__ = ["Adjoint"]
