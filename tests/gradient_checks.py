"""The total-derivative check shared by the gradient tests: a Taylor test of the adjoint
gradient (remainder rate 2 when it is right, ~1 when a term is missing) and a central
difference along the same direction."""

from adjoint.checks import central_difference, relative_error, taylor_test


def check_total_derivative(P, gamma, direction, eps0=1e-2):
    """``(Taylor result, relative error of the central difference with h = eps0 / 100, f0)``
    for the objective of problem ``P`` at design ``gamma``."""
    f0, df = P.evaluate(gamma)
    fun = lambda g: P.evaluate(g)[0]
    t = taylor_test(fun, gamma, df, direction, eps0=eps0, steps=4, f0=f0)
    cd = central_difference(fun, gamma, direction, 1e-2 * eps0)
    return t, relative_error(cd, df @ direction), f0
