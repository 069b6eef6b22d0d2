"""Continuation parameters are inputs of every solve: no stage leaks into the next one.

The reproduction of issue 11: on the optimization scene at h = 0.1 with beta fixed at 16,
evaluating a design at SIMP penalty 1 and then switching to penalty 3 must give the value a
fresh problem at penalty 3 gives (the structure's factorization used to be cached by rho
alone, so the second value was the penalty-1 one). The same for the Brinkman q.
"""

import dataclasses

import numpy as np
import pytest

import tofsi

from conftest import load

BASE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.beta=[16.0]"]


def perturbed_uniform(P, seed=0):
    rng = np.random.default_rng(seed)
    return P.initial_design() + 0.05 * rng.uniform(-1, 1, P.n_design)


@pytest.mark.parametrize("first,second,key", [(1.0, 3.0, "penalty"), (0.01, 0.1, "q")])
def test_a_stage_change_at_constant_beta_equals_a_fresh_problem(first, second, key):
    schedule = "design.penalty" if key == "penalty" else "design.brinkman_q"
    P = tofsi.Problem(load("beam_in_channel_optimization", *BASE, f"{schedule}=[{first}]"))
    gamma = perturbed_uniform(P)
    field = "penalty" if key == "penalty" else "brinkman_q"
    P.set_stage(dataclasses.replace(P.params, beta=16.0, **{field: first}))
    f_first, _ = P.evaluate(gamma)
    P.set_stage(dataclasses.replace(P.params, **{field: second}))
    f_second, df_second = P.evaluate(gamma)
    fresh = tofsi.Problem(load("beam_in_channel_optimization", *BASE, f"{schedule}=[{second}]"))
    f_fresh, df_fresh = fresh.evaluate(gamma)
    # the same problem; only the warm start differs (Newton tolerances ~1e-10)
    assert f_second == pytest.approx(f_fresh, rel=1e-8)
    np.testing.assert_allclose(df_second, df_fresh, rtol=1e-6, atol=1e-8 * np.abs(df_fresh).max())
    assert abs(f_first - f_fresh) > 1e-3 * abs(f_fresh)          # and the stages do differ


def test_the_old_keys_are_aliases_that_warn_and_conflicts_are_errors():
    with pytest.warns(FutureWarning, match="design.penalty"):
        scene = load("beam_in_channel_optimization", "structure.simp_penalty=2.0", "design.penalty=[2.0, 3.0]")
    assert scene.design.penalty == (2.0, 3.0)
    with pytest.warns(FutureWarning, match="design.brinkman_q"):
        scene = load("beam_in_channel", "fluid.brinkman_q=0.05")
    assert scene.design.brinkman_q == (0.05,)
    with pytest.warns(FutureWarning), pytest.raises(tofsi.core.errors.InputError) as err:
        load("beam_in_channel_optimization", "structure.simp_penalty=2.0")   # schedule starts at 3
    assert err.value.key == "structure.simp_penalty"


def test_a_solve_before_evaluate_gives_the_right_gradient_on_a_monolithic_scene():
    """No temporal coupling: the state owns its linearizations, so a solve before evaluate
    cannot break the adjoint (resetting the solvers between them once raised AttributeError)."""
    from adjoint.checks import central_difference, relative_error
    overrides = [*BASE, "effects.coupling=two-way", "mover.name=yeoh", "coupled.method=monolithic",
                 "structure.youngs_modulus=2e4", "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13",
                 "coupled.tol=1e-12", "mover.yeoh.newton_tol=1e-13", "design.beta=[0.0]"]
    P = tofsi.Problem(load("beam_in_channel_optimization", *overrides))
    gamma = perturbed_uniform(P, seed=4)
    P.solve(gamma)
    f, df = P.evaluate(gamma)
    d = np.random.default_rng(5).normal(size=P.n_design)
    cd = central_difference(lambda g: P.evaluate(g)[0], gamma, d, 1e-4)
    assert relative_error(cd, df @ d) < 1e-6
