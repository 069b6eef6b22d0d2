"""Exact flows for verification, and error norms of a Taylor-Hood solution."""

import numpy as np

from tofsi.fem.geometry import map_points, physical_gradients
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions
from tofsi.mesh.structured import StructuredQuadMesh

PI = np.pi


def _a(s):           # a = sin^2(pi s) and its derivatives
    return (np.sin(PI * s) ** 2, PI * np.sin(2 * PI * s), 2 * PI**2 * np.cos(2 * PI * s),
            -4 * PI**3 * np.sin(2 * PI * s))


class Manufactured:
    """Stream function psi = sin^2(pi x) sin^2(pi y) on [0, 1]^2, p = cos(pi x) cos(pi y)."""

    def __init__(self, mu=1.0, rho=0.0, alpha=0.0):
        self.mu, self.rho, self.alpha = mu, rho, alpha

    def velocity(self, P):
        ax, ay = _a(P[..., 0]), _a(P[..., 1])
        return np.stack([ax[0] * ay[1], -ax[1] * ay[0]], -1)

    def gradient(self, P):
        ax, ay = _a(P[..., 0]), _a(P[..., 1])
        return np.stack([np.stack([ax[1] * ay[1], ax[0] * ay[2]], -1),
                         np.stack([-ax[2] * ay[0], -ax[1] * ay[1]], -1)], -2)

    def pressure(self, P):
        return np.cos(PI * P[..., 0]) * np.cos(PI * P[..., 1])

    def force(self, P):
        ax, ay = _a(P[..., 0]), _a(P[..., 1])
        lap = np.stack([ax[2] * ay[1] + ax[0] * ay[3], -(ax[3] * ay[0] + ax[1] * ay[2])], -1)
        v, L = self.velocity(P), self.gradient(P)
        conv = np.einsum("...ij,...j->...i", L, v)
        gradp = np.stack([-PI * np.sin(PI * P[..., 0]) * np.cos(PI * P[..., 1]),
                          -PI * np.cos(PI * P[..., 0]) * np.sin(PI * P[..., 1])], -1)
        return self.rho * conv - self.mu * lap + gradp + self.alpha * v


class Kovasznay:
    """Kovasznay (1948) flow at Reynolds number Re (mu = 1/Re, rho = 1)."""

    def __init__(self, Re=40.0):
        self.lam = Re / 2 - np.sqrt(Re**2 / 4 + 4 * PI**2)

    def velocity(self, P):
        x, y, lam = P[..., 0], P[..., 1], self.lam
        e = np.exp(lam * x)
        return np.stack([1 - e * np.cos(2 * PI * y), lam / (2 * PI) * e * np.sin(2 * PI * y)], -1)

    def gradient(self, P):
        x, y, lam = P[..., 0], P[..., 1], self.lam
        e = np.exp(lam * x)
        c, s = np.cos(2 * PI * y), np.sin(2 * PI * y)
        return np.stack([np.stack([-lam * e * c, 2 * PI * e * s], -1),
                         np.stack([lam**2 / (2 * PI) * e * s, lam * e * c], -1)], -2)

    def pressure(self, P):
        return 0.5 * (1 - np.exp(2 * self.lam * P[..., 0]))


def errors(flow, w, exact, x=None):
    """(velocity L2, velocity H1 seminorm, pressure L2 up to a constant) errors, 5x5 Gauss."""
    pts, wts = gauss_square(5)
    Xe = flow.corners(x)
    N2, _ = shape_functions(2, pts)
    N1, _ = shape_functions(1, pts)
    grad, det = physical_gradients(Xe, 2, pts)
    ve, pe = flow.split(w)
    P = map_points(Xe, pts)
    W = det * wts
    vh = np.matmul(N2, ve)
    Lh = np.matmul(np.swapaxes(ve, 1, 2)[:, None], grad)
    ph = np.matmul(pe, N1.T)
    p = exact.pressure(P)
    dp = (ph - np.sum(W * ph) / W.sum()) - (p - np.sum(W * p) / W.sum())
    return (np.sqrt(np.sum(W[..., None] * (vh - exact.velocity(P)) ** 2)),
            np.sqrt(np.sum(W[..., None, None] * (Lh - exact.gradient(P)) ** 2)),
            np.sqrt(np.sum(W * dp**2)))


def rates(errs, hs):
    e, h = np.asarray(errs), np.asarray(hs)
    return np.log(e[:-1] / e[1:]) / np.log(h[:-1] / h[1:])


def unit_square(n, moved=False):
    """The n x n unit-square mesh and, with ``moved``, a smooth interior mesh motion ``x`` that
    keeps the boundary (an ALE-moved mesh for the manufactured solutions); else ``x = None``."""
    mesh = StructuredQuadMesh(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    x = None
    if moved:
        X = mesh.points
        bump = np.sin(PI * X[:, 0]) * np.sin(PI * X[:, 1])
        x = 0.08 * np.column_stack([bump * np.cos(2 * X[:, 1]), 0.6 * bump * np.sin(3 * X[:, 0])])
    return mesh, x
