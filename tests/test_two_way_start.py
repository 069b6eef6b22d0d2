"""The first two-way solve of a stage, and a warm start the direct Newton cannot carry.

The large-deformation scene at 40 x 20 after its three one-way stages (the design and the
state the optimizer carries into the first two-way stage). Truths: a converged state satisfies
every block's residual of the full problem (the caller's densities, the full inflow, the stage's
record) to the coupling tolerance; the path it took is in its report; where the direct Newton
from the one-way state converges, no ramp is taken (with a structure stiff enough that it does),
and where it does not (a softer one), the inflow is cut back to half and no further than needed,
not ramped up from rest in small steps. A stage change too large for a short direct Newton is
carried by the densities' path to the state a long direct Newton reaches.
"""

import tempfile

import numpy as np
import pytest

import tofsi
from tofsi.coupling.coupled import continuation
from tofsi.core.errors import NumericalError
from tofsi.optimization.optimize import Optimizer

from conftest import load

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
