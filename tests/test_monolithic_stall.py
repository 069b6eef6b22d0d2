"""The monolithic Newton's stall rule: a crawling Newton stops after a bounded number of steps.

Truth: a cycle of two scalar blocks with residuals ``r_a = z_a``, ``r_b = z_b`` (root 0) whose
linear solver returns a step 100 times too short, so every full step is accepted and leaves
0.99 of the merit: the residual halves only after 69 steps. The stall rule must stop it after
``DESIGN_STALL_ITERATIONS`` Newton steps when it starts from a converged state of the cycle and
is no load step (a design change: an optimizer's failing trial design crawls so), after
``STALL_ITERATIONS`` from rest or in a step of the inflow ramp; without the rule it would run
to ``max_iter`` (60).
"""

from types import SimpleNamespace

import numpy as np
import pytest

from tofsi.core.errors import NumericalError
from tofsi.coupling.monolithic import DESIGN_STALL_ITERATIONS, STALL_ITERATIONS, solve_monolithic

SHORTFALL = 100.0      # the fake solver's step is the Newton step divided by this


class Block:
    size, inputs = 1, ()

    def __init__(self, name):
        self.name = name

    def residual(self, values, rho, params):
        return np.array(values[self.name], dtype=float)

    def linearize(self, values, rho, params):
        return SimpleNamespace(residual=self.residual(values, rho, params), coupling=lambda other: None)

    def residual_scale(self, values, rho, params, lin):
        return 1.0


class CrawlingSystem:
    """Just what :func:`solve_monolithic` asks of a block system, with a too-short step."""

    def __init__(self):
        self.settings = SimpleNamespace(tol=1e-9, max_iter=60, quasi_newton=False)
        self.by_name = {n: Block(n) for n in ("a", "b")}

    def start(self, comp, fields, state, direct=False, tol=None):
        for n in comp:
            if fields[n] is None:
                fields[n] = np.ones(1)

    def linear_solver(self, comp):
        return SimpleNamespace(solver=None, last_excess=None, solve=lambda J, b, rtol: b / SHORTFALL)

    def block_jacobian(self, lins, comp, kept=None, at=None):
        return SimpleNamespace(assembled=True)

    def split(self, step, comp):
        return {"a": step[:1], "b": step[1:]}


def newton_steps(fields, load_step=False):
    state = SimpleNamespace(rho=np.zeros(1), params=None, linearizations={}, coupled={}, reports={})
    with pytest.raises(NumericalError, match="stagnated") as err:
        solve_monolithic(CrawlingSystem(), ("a", "b"), fields, state, load_step=load_step)
    history = err.value.diagnostic["history"]
    merits = [max(h["a"], h["b"]) for h in history]
    assert np.allclose(np.diff(np.log(merits)), np.log(1.0 - 1.0 / SHORTFALL))   # every step: 0.99 of the merit
    return len(history) - 1


def test_a_design_change_that_crawls_stops_after_the_design_stall_window():
    assert DESIGN_STALL_ITERATIONS < STALL_ITERATIONS
    converged = {"a": np.array([0.3]), "b": np.array([-0.2])}
    assert newton_steps(converged) == DESIGN_STALL_ITERATIONS


@pytest.mark.parametrize("start, load_step", [("rest", False), ("converged", True)])
def test_a_solve_from_rest_or_a_load_step_keeps_the_longer_window(start, load_step):
    fields = {"a": None, "b": None} if start == "rest" else {"a": np.array([0.3]), "b": np.array([-0.2])}
    assert newton_steps(fields, load_step=load_step) == STALL_ITERATIONS


def test_the_rule_stops_only_a_crawl():
    """A step half the Newton step's (the merit halves at each step) converges, in 29 steps."""
    system = CrawlingSystem()
    system.linear_solver = lambda comp: SimpleNamespace(solver=None, last_excess=None, solve=lambda J, b, rtol: b / 2.0)
    state = SimpleNamespace(rho=np.zeros(1), params=None, linearizations={}, coupled={}, reports={})
    fields = {"a": np.array([0.3]), "b": np.array([-0.2])}
    solve_monolithic(system, ("a", "b"), fields, state)
    steps = int(np.ceil(np.log2(0.3 / system.settings.tol)))        # 0.3 / 2^29 <= 1e-9
    assert len(state.reports["coupling"]["history"]) == steps + 1 == 30
