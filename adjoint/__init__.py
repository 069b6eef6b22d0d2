"""Adjoint sensitivities: derivative blocks, the block adjoint solve, gradient checks.

    from adjoint import Adjoint
    adj = Adjoint(model, state)          # refuses an unconverged state
    df_drho = adj.gradient(quantity)     # total derivative with respect to the element densities
"""

from adjoint.solve import Adjoint

__all__ = ["Adjoint"]
