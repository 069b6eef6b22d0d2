"""Slow, loop-by-loop element kernels: test oracles for the vectorized ones.

Written from the textbook formulas directly (one element, one quadrature
point, one index at a time), sharing no code with the library.
"""

import math

import numpy as np

GAUSS2 = [(-1 / math.sqrt(3), -1 / math.sqrt(3)), (1 / math.sqrt(3), -1 / math.sqrt(3)),
          (-1 / math.sqrt(3), 1 / math.sqrt(3)), (1 / math.sqrt(3), 1 / math.sqrt(3))]
CORNERS = [(-1, -1), (1, -1), (1, 1), (-1, 1)]


def q1_at(xi, eta, X):
    """Shape functions, physical gradients (4, 2) and det J of one quad at (xi, eta)."""
    N = [0.25 * (1 + a * xi) * (1 + b * eta) for a, b in CORNERS]
    dN = [[0.25 * a * (1 + b * eta), 0.25 * b * (1 + a * xi)] for a, b in CORNERS]
    J = np.zeros((2, 2))
    for k in range(4):
        for i in range(2):
            for a in range(2):
                J[i, a] += X[k][i] * dN[k][a]
    det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
    Jinv = np.linalg.inv(J)
    grad = np.array([[dN[k][0] * Jinv[0, i] + dN[k][1] * Jinv[1, i] for i in range(2)] for k in range(4)])
    return N, grad, det


# ---- springs (Farhat et al. 1998, the paper's matrices verbatim) -----------------------
def lineal_spring(p, q):
    """4x4 truss matrix (1/L)[[c^2, cs, -c^2, -cs], ...] of the edge p-q."""
    dx, dy = q[0] - p[0], q[1] - p[1]
    L = math.hypot(dx, dy)
    alpha = math.atan2(dy, dx)
    c, s = math.cos(alpha), math.sin(alpha)
    return (1 / L) * np.array([[c * c, s * c, -c * c, -s * c], [s * c, s * s, -s * c, -s * s],
                               [-c * c, -s * c, c * c, s * c], [-s * c, -s * s, s * c, s * s]])


def torsional_spring(P):
    """R^T C R of triangle P (3, 2), rows of R written out as in the paper."""
    def a(i, j):
        return (P[j][0] - P[i][0]) / ((P[j][0] - P[i][0]) ** 2 + (P[j][1] - P[i][1]) ** 2)

    def b(i, j):
        return (P[j][1] - P[i][1]) / ((P[j][0] - P[i][0]) ** 2 + (P[j][1] - P[i][1]) ** 2)

    i, j, k = 0, 1, 2
    R = np.array([
        [b(i, k) - b(i, j), a(i, j) - a(i, k), b(i, j), -a(i, j), -b(i, k), a(i, k)],
        [-b(j, i), a(j, i), b(j, i) - b(j, k), a(j, k) - a(j, i), b(j, k), -a(j, k)],
        [b(k, i), -a(k, i), -b(k, j), a(k, j), b(k, j) - b(k, i), a(k, i) - a(k, j)]])
    area = 0.5 * abs((P[1][0] - P[0][0]) * (P[2][1] - P[0][1]) - (P[2][0] - P[0][0]) * (P[1][1] - P[0][1]))

    def L2(p, q):
        return (P[q][0] - P[p][0]) ** 2 + (P[q][1] - P[p][1]) ** 2
    C = np.diag([L2(i, j) * L2(i, k) / (4 * area**2), L2(j, i) * L2(j, k) / (4 * area**2),
                 L2(k, i) * L2(k, j) / (4 * area**2)])
    return R.T @ C @ R


def spring_triangle(P, tsc=1.0):
    K = np.zeros((6, 6))
    for p, q in ((0, 1), (1, 2), (2, 0)):
        idx = [2 * p, 2 * p + 1, 2 * q, 2 * q + 1]
        K[np.ix_(idx, idx)] += 0.5 * lineal_spring(P[p], P[q])
    return K + tsc * torsional_spring(P)


def spring_quad(X, diagonal, tsc=1.0):
    """8x8 spring matrix of one quad: '1-3', '2-4' or 'both' (mean of the two)."""
    splits = {"1-3": [(0, 1, 2), (0, 2, 3)], "2-4": [(0, 1, 3), (1, 2, 3)]}
    names = ["1-3", "2-4"] if diagonal == "both" else [diagonal]
    K = np.zeros((8, 8))
    for name in names:
        for tri in splits[name]:
            idx = [d for n in tri for d in (2 * n, 2 * n + 1)]
            K[np.ix_(idx, idx)] += spring_triangle([X[n] for n in tri], tsc) / len(names)
    return K


# ---- plane-strain elasticity ------------------------------------------------------------
def elastic_quad(X, E, nu, chi=0.0):
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    K = np.zeros((8, 8))
    for xi, eta in GAUSS2:
        _, g, det = q1_at(xi, eta, X)
        for a in range(4):
            for b in range(4):
                for i in range(2):
                    for j in range(2):
                        # C_ijkl = lam d_ij d_kl + mu (d_ik d_jl + d_il d_jk), K_aibj = g_ak C_ikjl g_bl
                        val = 0.0
                        for k in range(2):
                            for l in range(2):
                                Cikjl = lam * (i == k) * (j == l) + mu * ((i == j) * (k == l) + (i == l) * (k == j))
                                val += g[a, k] * Cikjl * g[b, l]
                        K[2 * a + i, 2 * b + j] += val * det ** (1 - chi)
    return K


# ---- Yeoh in 3D with F33 = 1, then restricted to the plane --------------------------------
def yeoh_S_D_3d(F2, A10, A20, A30, kappa):
    F = np.eye(3)
    F[:2, :2] = F2
    C = F.T @ F
    Ci = np.linalg.inv(C)
    I1, I3 = np.trace(C), np.linalg.det(C)
    a = I3 ** (-1 / 3)
    J = math.sqrt(I3)
    t = I1 * a - 3
    W1 = A10 + 2 * A20 * t + 3 * A30 * t * t
    W11 = 2 * A20 + 6 * A30 * t
    I = np.eye(3)
    dJ1 = a * (I - I1 / 3 * Ci)
    S = 2 * W1 * dJ1 + 2 * kappa * (J - 1) * J * Ci
    D = np.zeros((3, 3, 3, 3))
    for i in range(3):
        for j in range(3):
            for k in range(3):
                for l in range(3):
                    sym = Ci[i, k] * Ci[j, l] + Ci[i, l] * Ci[j, k]
                    d2J1 = (-(a / 3) * (I[i, j] * Ci[k, l] + Ci[i, j] * I[k, l])
                            + a * I1 / 9 * Ci[i, j] * Ci[k, l] + a * I1 / 6 * sym)
                    D[i, j, k, l] = (4 * (W11 * dJ1[i, j] * dJ1[k, l] + W1 * d2J1)
                                     + 2 * kappa * ((2 * J * J - J) * Ci[i, j] * Ci[k, l] - (J * J - J) * sym))
    return S[:2, :2], D[:2, :2, :2, :2]


def add_gauss_point(R, K, det, g, F, S, D):
    """Add one Gauss point's share (weight ``det``) of a total-Lagrangian quad's internal forces
    ``R_ai = int P_iJ dN_a/dX_J`` (``P = F S``) and tangent ``K_(ai)(bk) = int dN_a/dX_J [S_JL
    delta_ik + F_iM D_MJNL F_kN] dN_b/dX_L`` (geometric and material parts), index by index;
    ``g``: the shape gradients (4, 2), ``S`` the second Piola-Kirchhoff stress, ``D = dS/dE``."""
    P = F @ S
    for a in range(4):
        for i in range(2):
            R[2 * a + i] += det * sum(P[i, J] * g[a, J] for J in range(2))
    for a in range(4):
        for i in range(2):
            for b in range(4):
                for k in range(2):
                    val = 0.0
                    for J in range(2):
                        for L in range(2):
                            val += g[a, J] * S[J, L] * g[b, L] * (i == k)   # geometric
                            for M in range(2):
                                for N in range(2):
                                    val += F[i, M] * g[a, J] * D[M, J, N, L] * F[k, N] * g[b, L]
                    K[2 * a + i, 2 * b + k] += det * val


def yeoh_quad(X, U, A10, A20, A30, kappa):
    """Residual (8,) and tangent (8, 8) of one quad, index by index."""
    R = np.zeros(8)
    K = np.zeros((8, 8))
    for xi, eta in GAUSS2:
        _, g, det = q1_at(xi, eta, X)
        F = np.eye(2) + sum(np.outer(U[a], g[a]) for a in range(4))
        S, D = yeoh_S_D_3d(F, A10, A20, A30, kappa)
        add_gauss_point(R, K, det, g, F, S, D)
    return R, K


# ---- inputs of the hyperelastic kernels' tests ---------------------------------------------------
def distorted_quads(n=4, seed=0):
    """``n`` quads ``(n, 4, 2)``: stretched unit squares with corners moved by up to 0.15."""
    rng = np.random.default_rng(seed)
    base = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return np.stack([base * rng.uniform(0.5, 2.0, 2) + rng.uniform(-0.15, 0.15, (4, 2)) for _ in range(n)])


def random_displacements(Xe, size, seed=1):
    """Element displacements ``(E, 8)`` uniform in ``[-size, size]``."""
    return size * np.random.default_rng(seed).uniform(-1, 1, (Xe.shape[0], 8))


def taylor_rates(residual_of_eps, slope):
    """Rates log2(r(eps)/r(eps/2)) of r(eps) = |f(eps) - f(0) - eps slope|, eps = 1e-2 / 2^k."""
    f0 = residual_of_eps(0.0)
    eps = 1e-2 / 2.0 ** np.arange(5)
    r = np.array([np.linalg.norm(residual_of_eps(e) - f0 - e * slope) for e in eps])
    return np.log2(r[:-1] / r[1:]), r

