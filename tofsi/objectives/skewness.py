"""The mesh-quality constraint's quantity: a soft minimum of the moved fluid mesh's corner skewness.

``q = KS_p(s_c(X + x))`` over the four corners of every quad of the mesh the
flow is solved on (:func:`tofsi.mesh.soft_quality.soft_min`: a smooth lower bound
of the worst corner's skewness, within ``log(4E)/p`` of it, and close to it
where few corners are near the worst), so the constraint ``q >= s`` keeps the
moved mesh away from folding. Its only partial is the one in the mesh
displacement ``x``, ``dq/dx = sum_c w_c ds_c/dX`` (analytic,
:func:`tofsi.mesh.soft_quality.corner_skewness_vjp`); the coupled adjoint carries
it through the mover and the structure to the densities. Not an objective (it
is not registered): a constraint of two-way stages (``design.min_skewness``).
"""

from __future__ import annotations


from tofsi.mesh.soft_quality import corner_skewness, corner_skewness_vjp, soft_min


class SoftMinSkewness:
    """``KS_p`` of the moved mesh's corner skewness (1 square corners, 0 degenerate, < 0 folded)."""

    name = "min skewness"

    def __init__(self, p: float):
        self.p = p

    def _moved(self, model, state):
        if state.x is None:
            raise ValueError("the mesh-quality constraint needs a moved mesh (a two-way state)")
        return model.mesh.points + state.mesh_displacement

    def value(self, model, state) -> float:
        return soft_min(corner_skewness(self._moved(model, state), model.mesh.quads), self.p)[0]

    def partials(self, model, state) -> dict:
        X = self._moved(model, state)
        _, weights = soft_min(corner_skewness(X, model.mesh.quads), self.p)
        return {"x": corner_skewness_vjp(X, model.mesh.quads, weights).ravel()}
