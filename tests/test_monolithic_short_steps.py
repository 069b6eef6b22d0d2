"""The monolithic Newton's short-step rule: a design change whose line search keeps cutting the
Newton step to a sliver stops after ``DESIGN_SHORT_STEPS`` such steps.

Truth: a cycle of two scalar blocks with residuals ``r_a = z_a``, ``r_b = z_b`` (root 0) whose
linear solver returns the Newton step times ``overshoot``. Along it the merit is
``|1 - alpha overshoot|`` of the last, so the backtracking line search (``alpha = 1, 1/2, ...``)
accepts the first ``alpha`` with ``alpha overshoot < 2``: with ``overshoot = 12``, ``alpha = 1/8``
(merit 1/2 of the last: the stall rule never fires) is accepted at every step; with 20,
``1/16`` (merit 1/4). A design change (from a converged state, no load step) whose steps are
cut to ``SHORT_STEP = 1/16`` must stop at its ``DESIGN_SHORT_STEPS``-th step; without the rule
it converges in 15 steps (29 at 1/8), as must the same crawl from rest or in a step of the inflow ramp, and
a design change whose steps are cut to 1/8 (the shortest of the large scene's converging design
changes at 160 x 80; benchmarks/README.md).
"""

from types import SimpleNamespace

import numpy as np
import pytest
from test_monolithic_stall import CrawlingSystem

from tofsi.core.errors import NumericalError
from tofsi.coupling.monolithic import DESIGN_SHORT_STEPS, SHORT_STEP, solve_monolithic


def overshooting(overshoot: float) -> CrawlingSystem:
    system = CrawlingSystem()
    system.linear_solver = lambda comp: SimpleNamespace(solver=None, last_excess=None, solve=lambda J, b, rtol: overshoot * b)
    return system


def solve(overshoot, start="converged", load_step=False):
    state = SimpleNamespace(rho=np.zeros(1), params=None, linearizations={}, coupled={}, reports={})
    fields = {"a": np.array([0.3]), "b": np.array([-0.2])} if start == "converged" else {"a": None, "b": None}
    solve_monolithic(overshooting(overshoot), ("a", "b"), fields, state, load_step=load_step)
    return state.reports["coupling"]["history"]


def test_a_design_change_cut_to_slivers_stops_at_its_third_short_step():
    assert SHORT_STEP == 1.0 / 16 and DESIGN_SHORT_STEPS == 3
    with pytest.raises(NumericalError, match="crawled") as err:
        solve(20.0)
    history = err.value.diagnostic["history"]
    assert [h["step_length"] for h in history] == [SHORT_STEP] * DESIGN_SHORT_STEPS
    merits = [max(h["a"], h["b"]) for h in history]
    assert np.allclose(np.diff(np.log(merits)), np.log(0.25))       # each step left 1/4: no stall


@pytest.mark.parametrize("overshoot, start, load_step, steps", [
    (20.0, "rest", False, 15), (20.0, "converged", True, 15), (12.0, "converged", False, 29)])
def test_the_rule_spares_a_solve_from_rest_a_load_step_and_steps_of_an_eighth(overshoot, start, load_step, steps):
    history = solve(overshoot, start, load_step)
    assert len(history) == steps + 1
    assert {h.get("step_length") for h in history[:-1]} == {1.0 / 16 if overshoot == 20.0 else 1.0 / 8}
