"""Stabilized Q1/Q1 through the whole model: every block and total derivative by Taylor tests
(one-way and two-way, each fluid load), and the drag against the no-slip limit.

The truths: Taylor remainders of rate 2 (a missing term gives ~1) and central differences of
the same functions; an independent no-slip computation (tests/no_slip.py: the body cut out of
the same mesh, the same element) for the drag.
"""

import numpy as np
import pytest

import tofsi
from adjoint.checks import check_blocks
from tofsi.coupling.coupled import CoupledModel
from tofsi.mesh.structured import SOLID

from conftest import load
from gradient_checks import check_total_derivative
from no_slip import NoSlipReference

BASE = ["fluid.element=q1q1", "mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13",
        "design.filter_radius=0.15", "coupled.tol=1e-12", "mover.yeoh.newton_tol=1e-13"]
TWO_WAY = ["design.coupling=[\"two-way\"]", "structure.load_exponent=3"]


def design(P, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.05, 0.95, P.n_design), rng.normal(size=P.n_design)


@pytest.mark.parametrize("load", ["reaction", "pressure", "stress-divergence"])
@pytest.mark.parametrize("coupling", ["one-way", "two-way"])
def test_every_block_passes_the_taylor_test(coupling, load):
    scene = "beam_in_channel_optimization" if coupling == "one-way" else "beam_in_channel_optimization_fsi"
    P = tofsi.Problem(load_scene(scene, coupling, f"structure.load={load}"))
    gamma, _ = design(P)
    rows = check_blocks(P.model.system, P.solve(gamma))
    expected = {"F_w", "F_rho", "S_w", "S_rho"} | ({"F_x", "S_x", "D_x", "D_u"} if coupling == "two-way" else set())
    assert {r["check"] for r in rows} >= expected
    assert all(r["passed"] for r in rows), [r for r in rows if not r["passed"]]


def load_scene(name, coupling, *overrides):
    extra = ["structure.youngs_modulus=2e4"] if coupling == "one-way" else TWO_WAY
    return load(name, *BASE, *extra, *overrides)


@pytest.mark.parametrize("objective, fluid, load", [
    ("compliance", "navier-stokes", "reaction"), ("compliance", "navier-stokes", "pressure"),
    ("dissipation-strain", "navier-stokes", "reaction"), ("dissipation", "stokes", "reaction"),
    ("pressure-drop", "navier-stokes", "reaction")])
def test_one_way_total_derivatives(objective, fluid, load):
    P = tofsi.Problem(load_scene("beam_in_channel_optimization", "one-way", f"design.objective={objective}",
                                 f"effects.fluid={fluid}", f"structure.load={load}"))
    gamma, d = design(P)
    t, err, _ = check_total_derivative(P, gamma, d)
    assert t.min_rate > 1.9, t
    assert err < 1e-5, err


@pytest.mark.parametrize("objective, load", [("compliance", "reaction"), ("compliance", "pressure"),
                                             ("dissipation", "reaction")])
def test_two_way_total_derivatives(objective, load):
    """The flow on the mesh the structure moves: F_x, S_x and the objective's x-partial by the
    complex step through the Q1/Q1 kernel."""
    P = tofsi.Problem(load_scene("beam_in_channel_optimization_fsi", "two-way", f"design.objective={objective}",
                                 f"structure.load={load}"))
    gamma, d = design(P, seed=1)
    t, err, _ = check_total_derivative(P, gamma, d)
    assert P.solve(gamma).x is not None
    assert t.min_rate > 1.9, t
    assert err < 1e-5, err


def test_foil_drag_converges_to_the_no_slip_drag_of_the_same_element():
    """Brinkman reaction load against the body cut out (Stokes, the foil): the gap falls like
    1/alpha as for Taylor-Hood (tests/test_fluid_force.py); the Q1/Q1 no-slip drag itself is
    within 1 % of Taylor-Hood's 15.397 on the same mesh."""
    alphas = [1e4, 1e5, 1e6, 1e7, 1e8, 1e9]
    drags = []
    for alpha in alphas:
        model = CoupledModel(load("foil_in_channel", "effects.fluid=stokes", "effects.structure=none",
                                  "fluid.element=q1q1", f"fluid.alpha_max={alpha}"))
        state = model.solve(model.densities())
        drags.append(model.figures(state)["drag"])
    ref = NoSlipReference(model.flow, model.mesh.region == SOLID)
    ref.solve()
    no_slip = ref.force()
    assert no_slip[0] == pytest.approx(15.397, rel=1e-2)
    gap = np.abs(np.array(drags) - no_slip[0]) / no_slip[0]
    assert np.all(np.diff(gap) < 0), gap
    assert np.all(gap[np.array(alphas) >= 1e7] < 5e-3), gap
    assert gap[-1] < 1e-4 and gap[-2] / gap[-1] == pytest.approx(10.0, rel=0.1)
