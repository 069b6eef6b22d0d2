"""The optimality-criteria update against a problem with a known optimum."""

import numpy as np
import pytest

from tofsi.optimization.oc import oc_step


@pytest.mark.parametrize("solid_bound", [True, False])
def test_oc_converges_to_the_kkt_point_of_a_separable_problem(solid_bound):
    """min sum c_e / y_e  s.t.  mean(y) <= V: the optimum is y_e = V n sqrt(c_e) / sum sqrt(c)
    (c_e / y_e^2 = lambda), inside the bounds for these c."""
    rng = np.random.default_rng(0)
    n, V = 200, 0.3
    c = rng.uniform(0.5, 2.0, n)
    to_y = (lambda g: g) if solid_bound else (lambda g: 1.0 - g)
    fraction = lambda g: float(np.mean(to_y(g)))
    gamma = to_y(np.full(n, V))                       # to_y is its own inverse
    for _ in range(200):
        y = to_y(gamma)
        df_dy = -c / y**2
        gamma = oc_step(gamma, df_dy if solid_bound else -df_dy, np.full(n, 1.0 / n), fraction, V, solid_bound)
    exact = V * n * np.sqrt(c) / np.sqrt(c).sum()
    np.testing.assert_allclose(to_y(gamma), exact, rtol=2e-3)
    assert fraction(gamma) <= V * (1 + 1e-3)          # the bisection's tolerance, as topFlow


def test_oc_respects_the_move_limit_and_the_box():
    rng = np.random.default_rng(1)
    n = 100
    gamma = rng.uniform(0, 1, n)
    df = rng.normal(size=n) * 10
    new = oc_step(gamma, df, np.full(n, 1.0 / n), lambda g: float(g.mean()), 0.48, True, move=0.1)
    assert np.all(np.abs(new - gamma) <= 0.1 + 1e-15) and np.all((new >= 0) & (new <= 1))
    assert new.mean() == pytest.approx(0.48, rel=1e-3)
    far = oc_step(gamma, df, np.full(n, 1.0 / n), lambda g: float(g.mean()), 0.1, True, move=0.1)
    np.testing.assert_array_equal(far, np.maximum(0.0, gamma - 0.1))    # out of reach: nearest
