"""Slow, loop-by-loop stabilized Q1/Q1 element residual: the oracle of the batched kernel.

Written from topFlow's weak form (Alexandersen 2023, ``analyticalElement.m``) one element,
one Gauss point, one index at a time, sharing no code with the library. Complex-safe, so its
complex-step derivatives are an exact reference for the kernel's Jacobian and partials.
"""

import math

import numpy as np

CORNERS = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
S = 1 / math.sqrt(3)
GAUSS2 = [(a, b, 1.0) for b in (-S, S) for a in (-S, S)]       # 2 x 2 Gauss points, unit weights


def at(xi, eta, X):
    """Shape functions, physical gradients [k][i] and det J of one quad at (xi, eta)."""
    N = [0.25 * (1 + a * xi) * (1 + b * eta) for a, b in CORNERS]
    dN = [(0.25 * a * (1 + b * eta), 0.25 * b * (1 + a * xi)) for a, b in CORNERS]
    J = [[sum(X[k][i] * dN[k][r] for k in range(4)) for r in range(2)] for i in range(2)]   # dx_i/dxi_r
    det = J[0][0] * J[1][1] - J[0][1] * J[1][0]
    inv = [[J[1][1] / det, -J[0][1] / det], [-J[1][0] / det, J[0][0] / det]]              # dxi_r/dx_i
    grad = [[dN[k][0] * inv[0][i] + dN[k][1] * inv[1][i] for i in range(2)] for k in range(4)]
    return N, grad, det


def residual(X, v, p, alpha, rho, mu, symmetric=False, force=None):
    """Element residual (12,) of one quad: X (4, 2), v (4, 2), p (4,); force(x, y) -> (2,)."""
    d1 = (X[2][0] - X[0][0], X[2][1] - X[0][1])
    d2 = (X[3][0] - X[1][0], X[3][1] - X[1][1])
    h2 = 0.5 * (d1[0] ** 2 + d1[1] ** 2 + d2[0] ** 2 + d2[1] ** 2)
    u0 = [0.25 * sum(v[k][i] for k in range(4)) for i in range(2)]
    inv_tau2 = 4 * (u0[0] ** 2 + u0[1] ** 2) / h2      # 1 / tau_adv^2, times rho^2 below
    tau_over_rho = (rho**2 * inv_tau2 + (12 * mu / h2) ** 2 + alpha**2) ** -0.5
    tau = rho * tau_over_rho
    R = [0.0 * X[0][0]] * 12
    for xi, eta, wq in GAUSS2:
        N, grad, det = at(xi, eta, X)
        w = wq * det
        u = [sum(N[k] * v[k][i] for k in range(4)) for i in range(2)]
        du = [[sum(grad[k][j] * v[k][i] for k in range(4)) for j in range(2)] for i in range(2)]
        pp = sum(N[k] * p[k] for k in range(4))
        dp = [sum(grad[k][i] * p[k] for k in range(4)) for i in range(2)]
        f = [0.0, 0.0]
        if force is not None:
            x = sum(N[k] * X[k][0] for k in range(4))
            y = sum(N[k] * X[k][1] for k in range(4))
            f = force(x, y)
        res = [alpha * u[i] + rho * sum(u[j] * du[i][j] for j in range(2)) + dp[i] - f[i] for i in range(2)]
        for a in range(4):
            for i in range(2):
                r = N[a] * (alpha * u[i] + rho * sum(u[j] * du[i][j] for j in range(2)) - f[i])
                for j in range(2):
                    r += mu * grad[a][j] * (du[i][j] + (du[j][i] if symmetric else 0.0))
                r -= grad[a][i] * pp
                r += tau * sum(u[j] * grad[a][j] for j in range(2)) * res[i]
                R[2 * a + i] = R[2 * a + i] + w * r
        for c in range(4):
            r = -N[c] * (du[0][0] + du[1][1]) - tau_over_rho * sum(grad[c][i] * res[i] for i in range(2))
            R[8 + c] = R[8 + c] + w * r
    return np.array(R)


def complex_step(fn, x, h=1e-30):
    """Columns ``d fn / d x_j`` of a complex-safe function of a real vector."""
    x = np.asarray(x, dtype=float)
    cols = []
    for j in range(x.size):
        xc = x.astype(complex)
        xc.flat[j] += 1j * h
        cols.append(np.asarray(fn(xc)).imag / h)
    return np.stack(cols, axis=-1)
