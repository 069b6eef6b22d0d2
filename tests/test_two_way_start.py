"""The first two-way solve of a stage, and a warm start the direct Newton cannot carry.

The large-deformation scene at 40 x 20 after its three one-way stages (the design and the
state the optimizer carries into the first two-way stage). Truths: a converged state satisfies
every block's residual of the full problem (the caller's densities, the full inflow, the stage's
record) to the coupling tolerance; the path it took is in its report; where the direct Newton
from the one-way state converges, no ramp is taken (with a structure stiff enough that it does:
its structure by Newton alone, the direct attempt takes no load steps), and where it does not (a
softer one), the inflow is cut back to half and no further than needed, not ramped up from rest
in small steps. Each step of the ramp starts its flow on the secant through the last two states,
which holds the step's own inflow (hand values). A stage change too large for a short direct
Newton is carried by the densities' path to the state a long direct Newton reaches.
"""

import tempfile

import numpy as np
import pytest

import tofsi
from tofsi.coupling.coupled import continuation
from tofsi.coupling.load_ramp import secant
from tofsi.core.blocks import Continuation, State
from tofsi.core.errors import NumericalError
from tofsi.optimization.optimize import Optimizer

from conftest import cyclic_garbage, load

COARSE = ["mesh.h_min=0.05", "mesh.h_max=0.05"]


@pytest.fixture(scope="module")
def one_way_start():
    """``(gamma, state)``: the design the three one-way stages reach and their last state."""
    problem = tofsi.Problem(load("beam_in_channel_optimization_large", *COARSE))
    with tempfile.TemporaryDirectory() as tmp:
        gamma = Optimizer(problem, tmp).design_after(3)
    state = problem.solve(gamma)
    assert state.x is None                                  # one-way: no mesh motion yet
    return gamma, state.data()


def first_two_way(gamma, guess, *overrides):
    problem = tofsi.Problem(load("beam_in_channel_optimization_large", *COARSE, *overrides))
    problem.set_stage(continuation(problem.scene, 3))       # two-way, finite strain, beta 8
    problem.set_guess(guess)
    return problem, problem.solve(gamma)


def assert_solves_the_full_problem(problem, state, gamma):
    model, tol = problem.model, problem.scene.coupled.tol
    assert state.params == problem.params and state.params.load == 1.0
    assert np.array_equal(state.rho, problem.densities(gamma))
    for block in model.system_for(state.stage).blocks:
        lin = block.linearize(state.fields, state.rho, state.params)
        scale = block.residual_scale(state.fields, state.rho, state.params, lin)
        assert np.linalg.norm(block.residual(state.fields, state.rho, state.params)) <= 10 * tol * scale


def test_a_first_two_way_solve_that_needs_no_ramp_goes_straight_from_the_one_way_state(one_way_start):
    gamma, guess = one_way_start
    problem, state = first_two_way(gamma, guess, "structure.youngs_modulus=4e3")
    assert "load_ramp" not in state.reports and "density_ramp" not in state.reports
    assert state.reports["structure"]["load_steps"] == 0             # the direct attempt: Newton alone
    assert len(state.reports["coupling"]["history"]) <= 12          # a few warm iterations' Newton steps
    assert np.abs(state.x).max() > 0.02                              # the mesh moved (2 % of the channel)
    assert_solves_the_full_problem(problem, state, gamma)


def test_a_first_two_way_solve_that_needs_the_ramp_cuts_back_from_the_full_inflow(one_way_start):
    """Softer, the direct Newton from the one-way state fails; the inflow goes to half, then on
    (not up from rest in quarter steps), and the state is the full problem's."""
    gamma, guess = one_way_start
    problem, state = first_two_way(gamma, guess, "structure.youngs_modulus=2e3")
    ramp = state.reports["load_ramp"]
    assert ramp["full_load_failure"]                                 # the full inflow was tried first
    assert ramp["steps"][0] == 0.5 and ramp["steps"][-1] == 1.0 and len(ramp["steps"]) <= 4
    assert_solves_the_full_problem(problem, state, gamma)
    with pytest.raises(NumericalError):                              # teeth: without the ramp it fails
        first_two_way(gamma, guess, "structure.youngs_modulus=2e3", "coupled.load_ramp=false")


def test_a_ramp_step_starts_its_flow_on_the_secant_which_holds_the_steps_inflow(one_way_start):
    """From rest the first step has no start (its sweep); the second starts its flow at the
    first's scaled by t / t_1, later ones on the secant; the structure and the mesh where the
    last step left them. The flow's prescribed values are linear in the load, so the start's
    fixed dofs hold the step's inflow (a Newton step, whose flow matrix eliminates the
    Dirichlet columns, need not move them)."""
    gamma, guess = one_way_start
    problem = tofsi.Problem(load("beam_in_channel_optimization_large", *COARSE))
    flow = problem.model.flow
    fixed = flow.bc.fixed
    rng = np.random.default_rng(1)

    def state_at(t):                         # a flow with the inflow at load t, anything inside
        w = rng.standard_normal(flow.size)
        w[fixed] = flow.boundary_values(Continuation(load=t))[fixed]
        return State(rho=guess.rho, fields={"w": w, "u": rng.standard_normal(4), "x": rng.standard_normal(4)})
    assert secant([(0.0, None)], 0.5, ("w",)) is None
    half, three_quarters = state_at(0.5), state_at(0.75)
    start = secant([(0.0, None), (0.5, half)], 1.0, ("w",))
    np.testing.assert_array_equal(start.w, 2.0 * half.w)
    assert start.u is half.u and start.x is half.x
    start = secant([(0.0, None), (0.5, half), (0.75, three_quarters)], 0.875, ("w",))
    np.testing.assert_allclose(start.w, three_quarters.w + 0.5 * (three_quarters.w - half.w), rtol=1e-15)
    np.testing.assert_allclose(start.w[fixed], flow.boundary_values(Continuation(load=0.875))[fixed],
                               rtol=1e-14, atol=1e-15)


def test_the_densities_carry_a_stage_change_the_direct_newton_cannot(one_way_start):
    """From the two-way state of the stage at beta 8, the same design at the next stage's beta 16
    with a Newton of 6 iterations: the densities' path (rho of beta 8 to rho of beta 16) reaches
    the state a Newton of 60 iterations reaches directly."""
    gamma, guess = one_way_start
    _, start = first_two_way(gamma, guess, "structure.youngs_modulus=4e3")

    def next_stage(*overrides):
        problem = tofsi.Problem(load("beam_in_channel_optimization_large", *COARSE, "structure.youngs_modulus=4e3",
                                     *overrides))
        problem.set_stage(continuation(problem.scene, 4))
        problem.set_guess(start.data())
        return problem, problem.solve(gamma)
    problem, state = next_stage("coupled.max_iter=6")
    path = state.reports["density_ramp"]
    assert path["full_load_failure"] and path["steps"][-1] == 1.0 and "load_ramp" not in state.reports
    assert_solves_the_full_problem(problem, state, gamma)
    _, direct = next_stage()
    assert "density_ramp" not in direct.reports
    for f in ("u", "x", "w"):
        ref = getattr(direct, f)
        assert np.abs(getattr(state, f) - ref).max() <= 1e-6 * np.abs(ref).max()
    with pytest.raises(NumericalError):                              # teeth: without the path it fails
        next_stage("coupled.max_iter=6", "coupled.load_ramp=false")


def test_a_ramped_solve_leaves_its_failed_attempt_to_no_cycle(one_way_start):
    """The failed full-inflow attempt is kept as its message: its exception's traceback would
    hold the ramp's frame, which held the exception -- a cycle that kept the failed attempt's
    states, moves and factorizations until Python's rare full collections (issue 32)."""
    gamma, guess = one_way_start
    (_, state), cyclic = cyclic_garbage(lambda: first_two_way(gamma, guess, "structure.youngs_modulus=2e3"))
    assert state.reports["load_ramp"]["full_load_failure"]           # teeth: the attempt failed
    assert not {"NumericalError", "State", "traceback"} & set(cyclic), cyclic


def test_when_the_direct_attempt_and_the_ramp_fail_the_full_inflow_is_tried_with_the_blocks_continuation():
    """A solve (a stand-in) that converges only at the full inflow with the blocks' own
    continuation (the route the direct attempt skips to fail fast): the ramp's failure is not
    the end; where that fails too, the ramp's failure is raised with the last attempt's."""
    from tofsi.coupling.load_ramp import ramped
    rho = np.ones(3)
    one_way = State(rho, {"w": np.ones(4), "u": np.ones(2), "x": None})
    calls = []

    def solve(params, guess, rho, direct=False, tol=None, load_step=False):
        calls.append((params.load, direct))
        if direct or params.load < 1.0:
            raise NumericalError("does not converge", {})
        return State(rho, {"w": np.ones(4), "u": np.ones(2), "x": np.ones(2)}, params, True)

    state = ramped(solve, Continuation(), one_way, 0.5, rho, ("w", "u", "x"), ("w",))
    assert calls == [(1.0, True), (0.5, False), (1.0, False)]        # direct, the ramp's half, the last resort
    assert state.reports["load_ramp"]["own_continuation"]
    assert "load continuation stopped at 0 of the inflow" in state.reports["load_ramp"]["ramp_failure"]

    def never(params, guess, rho, direct=False, tol=None, load_step=False):
        raise NumericalError(f"fails at {params.load} ({'direct' if direct else 'own continuation'})", {})

    with pytest.raises(NumericalError, match="load continuation stopped") as failed:
        ramped(never, Continuation(), one_way, 0.5, rho, ("w", "u", "x"), ("w",))
    assert failed.value.diagnostic["own_continuation_failure"] == "fails at 1.0 (own continuation)"


def test_a_ramp_step_short_of_the_end_is_solved_loosely_and_the_end_to_the_problems_tolerance():
    """A stand-in that fails directly at the full inflow and at 0.5: the ramp's steps (0.25,
    0.625, 1), load steps, ask for ``STEP_TOL`` below the end and for the problem's own
    tolerance (None) at it; the densities' steps are design changes, each to the problem's."""
    from tofsi.coupling.load_ramp import STEP_TOL, ramped
    rho = np.ones(3)
    one_way = State(rho, {"w": np.ones(4), "u": np.ones(2), "x": None})
    calls = []

    def solve(params, guess, rho, direct=False, tol=None, load_step=False):
        calls.append((params.load, direct, tol))
        assert load_step == (not direct)
        if direct or params.load == 0.5:
            raise NumericalError("does not converge", {})
        return State(rho, {"w": np.ones(4), "u": np.ones(2), "x": np.ones(2)}, params, True)

    state = ramped(solve, Continuation(), one_way, 0.1, rho, ("w", "u", "x"), ("w",))
    assert state.reports["load_ramp"]["steps"] == [0.25, 0.625, 1.0]
    assert calls == [(1.0, True, None), (0.5, False, STEP_TOL), (0.25, False, STEP_TOL),
                     (0.625, False, STEP_TOL), (1.0, False, None)]
    solved = State(np.zeros(3), {"w": np.ones(4), "u": np.ones(2), "x": np.ones(2)})
    tols = []

    def design_step(params, guess, rho, direct=False, tol=None, load_step=False):
        assert not load_step
        tols.append((float(rho[0]), tol))
        if rho[0] == 1.0 and guess is solved:                      # the design itself from afar fails
            raise NumericalError("does not converge", {})
        return State(rho, dict(solved.fields), params, True)

    ramped(design_step, Continuation(), solved, 0.1, rho, ("w", "u", "x"), ("w",))
    assert tols == [(1.0, None), (0.5, None), (1.0, None)]


def test_the_ramps_first_step_starts_from_the_flow_the_failed_attempt_solved():
    """A stand-in whose direct attempt fails after its sweep solved the flow (the error's
    ``solved``): the ramp's first step starts from that flow scaled by its inflow (hand values:
    the secant from rest through it), the structure and the mesh unset; the next step from the
    secant as before. An attempt that solved nothing leaves the first step at rest (None)."""
    from tofsi.coupling.load_ramp import ramped
    rho = np.ones(3)
    one_way = State(rho, {"w": np.ones(4), "u": np.ones(2), "x": None})
    w_full = np.array([1.0, 2.0, 3.0, 4.0])
    starts = []

    def solve(params, guess, rho, direct=False, tol=None, load_step=False):
        if direct:
            err = NumericalError("the structure's Newton stalls", {})
            err.solved = {"w": w_full.copy()}
            raise err
        starts.append((params.load, guess))
        return State(rho, {"w": params.load * w_full + 0.1, "u": np.ones(2), "x": np.ones(2)}, params, True)

    ramped(solve, Continuation(), one_way, 0.1, rho, ("w", "u", "x"), ("w",))
    (t1, first), (t2, second) = starts
    assert t1 == 0.5 and t2 == 1.0
    np.testing.assert_array_equal(first.w, 0.5 * w_full)
    assert first.u is None and first.x is None and np.array_equal(first.rho, rho)
    np.testing.assert_allclose(second.w, 2.0 * (0.5 * w_full + 0.1), rtol=1e-15)   # the secant from rest

    starts.clear()

    def nothing_solved(params, guess, rho, direct=False, tol=None, load_step=False):
        if direct:
            raise NumericalError("the flow fails", {})
        return solve(params, guess, rho, direct, tol, load_step)
    ramped(nothing_solved, Continuation(), one_way, 0.1, rho, ("w", "u", "x"), ("w",))
    assert starts[0][1] is None                                       # from rest


def test_a_failed_direct_attempt_leaves_its_flow_which_solves_the_full_inflow_at_rest(one_way_start):
    """The shipped (soft) structure: the direct attempt's sweep solves the flow, then the
    structure's Newton stalls; the error carries that flow (nothing else), and it satisfies the
    flow's own residual at the full inflow on the mesh at rest to the sweep's tolerance (truth:
    the residual evaluated anew)."""
    from tofsi.coupling.monolithic import SWEEP_TOL
    gamma, guess = one_way_start
    problem = tofsi.Problem(load("beam_in_channel_optimization_large", *COARSE, "structure.youngs_modulus=2e3"))
    problem.set_stage(continuation(problem.scene, 3))
    system = problem.model.system_for(problem.stage)
    rho, params = problem.densities(gamma), problem.stage.params
    with pytest.raises(NumericalError, match="structure") as failed:
        system.solve(rho, params, guess, direct=True)
    assert set(failed.value.solved) == {"w"}
    fields = {"w": failed.value.solved["w"], "u": None, "x": np.zeros(system.by_name["x"].size)}
    block = system.by_name["w"]
    lin = block.linearize(fields, rho, params)
    scale = block.residual_scale(fields, rho, params, lin)
    assert np.linalg.norm(block.residual(fields, rho, params)) <= SWEEP_TOL * scale
    np.testing.assert_allclose(fields["w"][block.fixed], problem.model.flow.boundary_values(params)[block.fixed])


class _Recorded:
    """A stand-in block whose residual is fixed (``value`` per unit of its scale) and whose
    evaluations are counted."""

    def __init__(self, name, size, inputs, value, calls):
        self.name, self.size, self.inputs, self.value, self.calls = name, size, inputs, value, calls

    def residual(self, values, rho, params):
        self.calls.append(self.name)
        return np.array([self.value, 0.0])

    def linearize(self, values, rho, params):
        block = self

        class Lin:
            @property
            def residual(self):
                return block.residual(values, rho, params)
        return Lin()


def test_a_line_search_trial_over_its_bound_skips_the_largest_block():
    """The merit of a monolithic Newton's trial: the largest scaled residual (hand values). The
    mesh (small, reading only the structure) is evaluated first, then the flow and the structure
    in their order (the structure's load reads the flow's pass); once one reaches the bound (the
    merit a trial must fall below) the rest are skipped and no linearizations are returned; a
    non-finite residual is inf."""
    from tofsi.coupling.monolithic import scaled_merit
    calls = []
    blocks = [_Recorded("w", 100, ("x",), 0.3, calls), _Recorded("u", 10, ("w", "x"), 0.5, calls),
              _Recorded("x", 10, ("u",), 8.0, calls)]
    scales = [1.0, 2.0, 4.0]                                          # scaled: w 0.3, u 0.25, x 2.0
    value, lins = scaled_merit(blocks, scales, {}, None, None, linearize=True)
    assert value == 2.0 and set(lins) == {"w", "u", "x"} and calls == ["x", "w", "u"]
    calls.clear()
    value, lins = scaled_merit(blocks, scales, {}, None, None, linearize=True, bound=1.5)
    assert value == 2.0 and lins is None and calls == ["x"]          # rejected: the flow never touched
    calls.clear()
    value, _ = scaled_merit(blocks, scales, {}, None, None, bound=2.5)
    assert value == 2.0 and calls == ["x", "w", "u"]                 # under the bound: every block
    blocks[1].value = np.nan
    assert scaled_merit(blocks, scales, {}, None, None)[0] == np.inf


def test_a_ramps_last_step_rebuilds_couplings_kept_from_far_once_near_the_solution(one_way_start, monkeypatch):
    """The step to the full inflow (E = 2.2 kPa: direct attempt fails, ramp 0.5, 1) keeps the slow
    couplings of its last far iterate (one whose predecessor contracted by less than
    ``SLOW_CONTRACTION``) and rebuilds them once more at the first iterate whose merit fell below
    ``NEAR_REBUILD`` of that iterate's, and nowhere else. Truths: the state satisfies the full
    problem's residuals, and it is the state the same Newton reaches without the rule (to the
    coupling tolerance), which takes no fewer Newton steps."""
    from tofsi.coupling import monolithic
    gamma, guess = one_way_start
    problem, state = first_two_way(gamma, guess, "structure.youngs_modulus=2.2e3")
    assert state.reports["load_ramp"]["steps"] == [0.5, 1.0]
    history = state.reports["coupling"]["history"]
    merits = [max(h[n] for n in ("w", "u", "x")) for h in history]
    rebuilt = [i for i, h in enumerate(history) if h.get("couplings_rebuilt")]
    far = [i for i in rebuilt if merits[i] > monolithic.SLOW_CONTRACTION * merits[i - 1]]
    near = [i for i in rebuilt if i not in far]
    assert far and len(near) == 1, (merits, rebuilt)
    k, built = near[0], max(i for i in far if i < near[0])
    assert merits[k] < monolithic.NEAR_REBUILD * merits[built] <= merits[k - 1]
    assert_solves_the_full_problem(problem, state, gamma)
    monkeypatch.setattr(monolithic, "NEAR_REBUILD", 0.0)              # the rule off
    _, without = first_two_way(gamma, guess, "structure.youngs_modulus=2.2e3")
    before = without.reports["coupling"]["history"]
    assert not any(h.get("couplings_rebuilt") for h in before[k:])       # teeth: nothing rebuilt there
    assert len(before) >= len(history)
    for f in ("u", "x", "w"):
        ref = getattr(without, f)
        assert np.abs(getattr(state, f) - ref).max() <= 1e-7 * np.abs(ref).max()
