"""Smooth aggregates of mesh quality and their derivatives with respect to the nodes.

The worst element's skewness is a minimum, not differentiable where the
worst corner changes. Tuning aggregates every corner's skewness with the
Kreisselmeier-Steinhauser (KS) soft minimum

    KS_p(s) = m - (1/p) log sum_c exp(-p (s_c - m)),    m = min_c s_c,

a lower bound of the minimum, ``m - log(N)/p <= KS_p <= m``, smooth in
``s`` with ``dKS/ds_c = w_c = exp(-p (s_c - m)) / sum exp(...)`` (weights
summing to 1, concentrated on the corners within about ``1/p`` of the
worst). The soft maximum is ``-KS_p(-s)``.

Corner skewness ``s = 1 - |theta - 90| / 90`` (degrees) with the signed
corner angle ``theta = atan2(cross, dot)`` of the edges leaving the corner
(:mod:`tofsi.mesh.quality`), here taken in [-90, 270) rather than [0, 360): the
two agree on every valid corner (0 < theta < 180), but a corner collapsing
through 0 degrees goes on continuously (``s`` slightly below 0) instead of
jumping to ``s = -2``, so the soft minimum stays continuous where a mover
folds a corner over, and its gradient still points back to valid meshes. With ``e_n``, ``e_p`` the edges to the next and the
previous corner, ``r^2 = cross^2 + dot^2``,

    d theta / d e_n = (dot (e_p,y, -e_p,x) - cross e_p) / r^2,
    d theta / d e_p = (dot (-e_n,y, e_n,x) - cross e_n) / r^2,

and the corner itself gets minus their sum (radians;
``ds/dtheta = -sign(theta - 90) (180/pi) / 90``). The area change
``A / A0`` (shoelace) has ``dA/dx_k = (y_{k+1} - y_{k-1}) / 2`` and
``dA/dy_k = (x_{k-1} - x_{k+1}) / 2``. Every function is batched over the
elements; gradients are ``(n, 2)`` arrays on the nodes.
"""

from __future__ import annotations

import numpy as np

from tofsi.mesh.quality import corner_angles, signed_area


def soft_min(values: np.ndarray, p: float) -> tuple[float, np.ndarray]:
    """KS soft minimum of ``values`` (any shape) and its weights ``dKS/dvalues`` (same shape)."""
    m = float(np.min(values))
    e = np.exp(-p * (values - m))
    total = float(e.sum())
    return m - np.log(total) / p, e / total


def soft_max(values: np.ndarray, p: float) -> tuple[float, np.ndarray]:
    """KS soft maximum ``-KS_p(-values)`` and its weights."""
    value, weights = soft_min(-np.asarray(values), p)
    return -value, weights


def corner_skewness(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Skewness of every corner ``(E, 4)``: ``1 - |theta - 90| / 90`` with theta in [-90, 270)."""
    return 1.0 - np.abs(_wrapped(corner_angles(points, quads)) - 90.0) / 90.0


def _wrapped(theta: np.ndarray) -> np.ndarray:
    """Corner angles [deg] in [-90, 270): a corner that collapses through 0 degrees goes on
    to small negative angles instead of jumping to 360 (the skewness is -1 at both ends)."""
    return np.mod(theta + 90.0, 360.0) - 90.0


def _scatter(quads: np.ndarray, corner_values: np.ndarray, n_nodes: int) -> np.ndarray:
    """Sum per-corner vectors ``(E, 4, 2)`` onto the nodes ``(n, 2)``."""
    out = np.zeros((n_nodes, 2))
    for i in range(2):
        out[:, i] = np.bincount(quads.ravel(), corner_values[..., i].ravel(), minlength=n_nodes)
    return out


def corner_skewness_vjp(points: np.ndarray, quads: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``sum_c weights_c ds_c/dX`` ``(n, 2)`` for corner weights ``(E, 4)``."""
    P = points[quads]                                   # (E, 4, 2)
    e_n = np.roll(P, -1, axis=1) - P
    e_p = np.roll(P, 1, axis=1) - P
    cross = e_n[..., 0] * e_p[..., 1] - e_n[..., 1] * e_p[..., 0]
    dot = np.einsum("eki,eki->ek", e_n, e_p)
    r2 = cross**2 + dot**2
    theta = _wrapped(np.degrees(np.arctan2(cross, dot)))
    ds_dtheta = -np.sign(theta - 90.0) * (180.0 / np.pi) / 90.0          # per radian
    c = (weights * ds_dtheta / r2)[..., None]                            # (E, 4, 1)
    perp_p = np.stack([e_p[..., 1], -e_p[..., 0]], axis=-1)
    perp_n = np.stack([-e_n[..., 1], e_n[..., 0]], axis=-1)
    g_n = c * (dot[..., None] * perp_p - cross[..., None] * e_p)          # on the next corner
    g_p = c * (dot[..., None] * perp_n - cross[..., None] * e_n)          # on the previous corner
    per_corner = np.roll(g_n, 1, axis=1) + np.roll(g_p, -1, axis=1) - g_n - g_p
    return _scatter(quads, per_corner, points.shape[0])


def area_change_vjp(points_ref: np.ndarray, points: np.ndarray, quads: np.ndarray,
                    weights: np.ndarray) -> np.ndarray:
    """``sum_e weights_e d(A_e/A0_e)/dX`` ``(n, 2)`` for element weights ``(E,)``."""
    P = points[quads]
    nxt, prv = np.roll(P, -1, axis=1), np.roll(P, 1, axis=1)
    dA = 0.5 * np.stack([nxt[..., 1] - prv[..., 1], prv[..., 0] - nxt[..., 0]], axis=-1)
    scale = (weights / signed_area(points_ref, quads))[:, None, None]
    return _scatter(quads, scale * dA, points.shape[0])
