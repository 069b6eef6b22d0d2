"""The solid's weight (structure.density, structure.gravity): a dead load on the solid phase.

* its resultant is the solid's weight, rho_s g times the solid area, exactly;
* a cantilever under its own weight deflects as Timoshenko's beam (the structure alone, no flow);
* the structure block's partials with the weight (S_rho carries psi'(rho) rho_s g int N) and
  the compliance's total derivative pass the Taylor test, with and without a flow, at small
  and finite strain; without the weight's density derivative the Taylor test fails.
"""

import json

import numpy as np
import pytest

import tofsi
from adjoint.checks import check_blocks
from conftest import load, scene_path
from gradient_checks import check_total_derivative
from tofsi.coupling.coupled import CoupledModel
from tofsi.physics.gravity import DeadLoad
from tofsi.core.blocks import Continuation
from tofsi.scene.scene import scene_from_dict

RHO_S, G = 1000.0, (0.0, -9.81)


def cantilever(h, **structure):
    """A beam 1 m x 0.1 m clamped on the left side of a 1.2 m x 0.5 m box, in void."""
    raw = {"name": "cantilever", "geometry": {"length": 1.2, "height": 0.5, "solids": [[0.0, 1.0, 0.2, 0.3]]},
           "mesh": {"h_min": h, "h_max": 0.05, "growth": 1.2}, "effects": {"structure": "linear-elastic"},
           "structure": {"youngs_modulus": 1e9, "poisson_ratio": 0.3, "clamped": ["left"], "density": RHO_S,
                         "gravity": list(G), **structure}}
    return CoupledModel(scene_from_dict(raw))


def test_the_weight_is_the_solids_weight():
    model = cantilever(0.025)
    rho = model.densities()
    fx, fy = model.structure.weight.resultant(rho)
    assert fx == 0.0 and fy == pytest.approx(RHO_S * G[1] * 1.0 * 0.1, rel=1e-13)
    f = model.structure.load(None, None, rho).reshape(-1, 2)
    assert f[:, 1].sum() == pytest.approx(fy, rel=1e-13)
    gray = np.full(model.mesh.n_elements, 0.5)                  # weighted like the fluid load: rho^k
    load = DeadLoad(model.mesh, RHO_S, G)
    assert load.resultant(gray, Continuation(load_exponent=3.0))[1] == pytest.approx(
        0.125 * RHO_S * G[1] * 1.2 * 0.5, rel=1e-13)


def test_a_cantilever_under_its_own_weight_deflects_as_timoshenkos_beam():
    """Tip deflection against q L^4 / (8 E' I) + q L^2 / (2 kappa G A) (plane strain
    E' = E / (1 - nu^2), kappa = 5/6). Q1 converges from the stiff side at second order (4, 8
    and 16 elements through the thickness); its Richardson extrapolation is within 1 % of the
    beam (the beam theory's own error: the clamped root's warping, the load on the axis)."""
    E, nu, L, t = 1e9, 0.3, 1.0, 0.1
    q = RHO_S * 9.81 * t
    exact = q * L ** 4 / (8 * E / (1 - nu ** 2) * t ** 3 / 12) + q * L ** 2 / (2 * 5 / 6 * E / (2 * (1 + nu)) * t)
    tips = []
    for h in (0.025, 0.0125, 0.00625):
        model = cantilever(h)
        state = model.solve(model.densities())
        P = model.mesh.points
        tip = np.flatnonzero(np.isclose(P[:, 0], 1.0) & np.isclose(P[:, 1], 0.25))
        tips.append(-state.u.reshape(-1, 2)[tip[0], 1])
    assert tips[0] < tips[1] < tips[2] < exact
    ratio = (tips[1] - tips[0]) / (tips[2] - tips[1])
    assert 1.7 < np.log2(ratio) < 2.3
    assert tips[2] + (tips[2] - tips[1]) / (ratio - 1) == pytest.approx(exact, rel=0.01)


BASE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.15", f"structure.density={RHO_S}",
        "structure.gravity=[0.3, -9.81]", "structure.youngs_modulus=1e5", "structure.e_min_ratio=1e-3",
        "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13", "structure.newton_tol=1e-13"]
CASES = {"weight alone": ["effects.fluid=none"],
         "weight and flow": [],
         "weight alone, neo-hookean": ["effects.fluid=none", "structure.model=neo-hookean",
                                       "structure.energy_threshold=0.3", "structure.energy_sharpness=8"]}


def problem(*overrides):
    return tofsi.Problem(load("beam_in_channel_optimization", *BASE, *overrides))


@pytest.mark.parametrize("case", list(CASES))
def test_blocks_and_total_derivative_with_the_weight(case):
    P = problem(*CASES[case])
    rng = np.random.default_rng(3)
    gamma, direction = rng.uniform(0.1, 0.9, P.n_design), rng.normal(size=P.n_design)
    state = P.solve(gamma)
    rows = check_blocks(P.model.system_for(state.stage), state)
    assert {r["check"] for r in rows} >= {"S_u", "S_rho"}
    assert ("F_w" in {r["check"] for r in rows}) == (case == "weight and flow")
    assert all(r["passed"] for r in rows), [r for r in rows if not r["passed"]]
    t, err, _ = check_total_derivative(P, gamma, direction)
    assert t.min_rate > 1.9 and err < 1e-5, (t, err)


def test_without_the_weights_density_derivative_the_taylor_test_fails(monkeypatch):
    monkeypatch.setattr(DeadLoad, "density_vectors", lambda self, rho, params=None: 0.0 * self.full)
    P = problem(*CASES["weight alone"])
    gamma = np.random.default_rng(3).uniform(0.1, 0.9, P.n_design)
    rows = {r["check"]: r for r in check_blocks(P.model.system_for(P.stage), P.solve(gamma))}
    assert not rows["S_rho"]["passed"]


def test_a_structure_without_flow_needs_a_weight(cli, tmp_path):
    run = cli("solve", str(scene_path("beam_in_channel_optimization")), "--set", "effects.fluid=none",
              "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1", "--output", str(tmp_path), "--json")
    assert run.returncode == 2 and "structure.density and structure.gravity" in run.stderr
    run = cli("solve", str(scene_path("beam_in_channel_optimization")), "--set", "effects.fluid=none",
              "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1", "--set", "structure.density=1000",
              "--set", "structure.gravity=[0, -9.81]", "--output", str(tmp_path / "w"), "--json")
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    assert figures["compliance"] > 0 and "drag" not in figures
