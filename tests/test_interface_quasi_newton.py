"""The interface quasi-Newton update (tofsi.core.iteration.InterfaceQuasiNewton) of a fixed point.

Truths: on an affine map ``H(x) = G x + c`` the multi-secant model is exact on the differences
it has seen, so after ``n + 1`` sweeps of an ``n``-dimensional map the iterate is the fixed point
``(I - G)^-1 c`` to round-off -- also when ``G`` has an eigenvalue beyond 1, where the plain
sweep diverges; a nonlinear map converges superlinearly.
"""

import numpy as np

from tofsi.core.iteration import InterfaceQuasiNewton


def affine(n: int, spectral_radius: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    eigen = np.linspace(-0.5, 0.5, n)
    eigen[0] = spectral_radius                          # one mode the plain sweep amplifies
    G = Q @ np.diag(eigen) @ Q.T
    c = rng.normal(size=n)
    return G, c, np.linalg.solve(np.eye(n) - G, c)


def test_an_affine_map_whose_sweep_diverges_is_solved_in_n_plus_one_sweeps():
    n = 8
    G, c, exact = affine(n, spectral_radius=-30.0)
    x, plain = np.zeros(n), np.zeros(n)
    iqn = InterfaceQuasiNewton(omega=0.5)
    for _ in range(n + 1):
        x = iqn.next(x, G @ x + c)
        plain = G @ plain + c
    assert np.linalg.norm(x - exact) <= 1e-10 * np.linalg.norm(exact)
    assert np.linalg.norm(plain - exact) > 1e6 * np.linalg.norm(exact)      # teeth: the sweep diverges


def test_a_nonlinear_map_converges_superlinearly():
    G, c, _ = affine(6, spectral_radius=2.0, seed=1)
    H = lambda x: G @ x + c + 0.05 * np.sin(x)
    x, iqn, changes = np.zeros(6), InterfaceQuasiNewton(omega=0.5), []
    for _ in range(14):
        h = H(x)
        changes.append(np.linalg.norm(h - x))
        x = iqn.next(x, h)
    assert changes[-1] <= 1e-12 * changes[0]
    assert np.linalg.norm(H(x) - x) <= 1e-12 * np.linalg.norm(x)


def test_only_the_last_columns_are_kept():
    iqn = InterfaceQuasiNewton(omega=0.5, columns=3)
    x = np.zeros(5)
    for k in range(7):
        x = iqn.next(x, np.full(5, float(k)) + 0.1 * x)
    assert len(iqn.V) == len(iqn.W) == 3
