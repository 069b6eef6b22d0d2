"""Adjoint sensitivities: derivative blocks, the block adjoint solve, gradient checks."""
