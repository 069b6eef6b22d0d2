"""The finite-strain structure in the coupled problem: every block and the total derivative.

One-way (flow then structure) and two-way, by monolithic Newton (Yeoh and linear movers) and
partitioned (spring mover), with ``structure.model = "neo-hookean"``: each block's transposed
partials (S_u the tangent, S_w, S_x the follower load, S_rho with the E'(rho) and g'(rho)
terms) against Taylor tests and central differences (adjoint.checks.check_blocks), and the
objective's total derivative through the adjoint (Taylor rate 2, central differences).
The structure is soft enough (E = 2 kPa, 8 cm motion) that finite strain changes the
displacement by 3.5 % from the linear model; ``WIDE`` spreads the blend g(rho) over the gray
densities so that its derivative enters the gradients of random designs.
"""

import numpy as np
import pytest

import tofsi
from adjoint.checks import check_blocks
from tofsi.physics.finite_strain import FiniteStrainElasticity

from conftest import load
from gradient_checks import check_total_derivative

BASE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13",
        "design.filter_radius=0.15", "structure.youngs_modulus=2e3", "structure.load_exponent=3",
        "structure.model=neo-hookean", "structure.newton_tol=1e-13", "coupled.tol=1e-12",
        "mover.yeoh.newton_tol=1e-13", "mover.linear.linear_tol=1e-14", "mover.spring.linear_tol=1e-14"]
WIDE = ["structure.energy_threshold=0.3", "structure.energy_sharpness=8"]
CASES = {
    "one-way": [],
    "monolithic yeoh": ["effects.coupling=two-way", "mover.name=yeoh", "coupled.method=monolithic"],
    "monolithic linear": ["effects.coupling=two-way", "mover.name=linear", "coupled.method=monolithic"],
    "partitioned spring": ["effects.coupling=two-way", "mover.name=spring", "mover.spring.increments=1",
                           "mover.spring.diagonals=both", "coupled.method=partitioned"],
}


def problem(*overrides):
    return tofsi.Problem(load("beam_in_channel_optimization", *BASE, *overrides))


def random_design(P, seed=1):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.05, 0.95, P.n_design), rng.normal(size=P.n_design)


def test_the_finite_strain_solve_differs_from_the_linear_one():
    """The cases below are in the nonlinear regime: 3-4 % between the two models."""
    us = []
    for model in ("linear", "neo-hookean"):
        P = problem(*CASES["monolithic yeoh"], f"structure.model={model}")
        us.append(P.solve(random_design(P)[0]).u)
    gap = np.linalg.norm(us[1] - us[0]) / np.linalg.norm(us[0])
    assert 0.02 < gap < 0.06, gap
    assert np.abs(us[0]).max() > 0.05


@pytest.mark.parametrize("interpolation", ["energy (wide)", "simp"])
@pytest.mark.parametrize("case", list(CASES))
def test_every_block_passes_the_taylor_test(case, interpolation):
    P = problem(*CASES[case], *(WIDE if interpolation.startswith("energy") else ["structure.interpolation=simp"]))
    gamma, _ = random_design(P)
    state = P.solve(gamma)
    if case != "one-way":
        assert state.reports["coupling"]["method"] == case.split()[0]
    rows = check_blocks(P.model.system_for(state.params), state)
    names = {r["check"] for r in rows}
    assert {"S_u", "S_w", "S_rho"} <= names and ("S_x" in names) == (case != "one-way")
    assert all(r["passed"] for r in rows), [r for r in rows if not r["passed"]]


@pytest.mark.parametrize("case", list(CASES))
def test_total_derivative_taylor_rate_two(case):
    P = problem(*CASES[case], *WIDE)
    gamma, d = random_design(P, seed=2)
    t, err, _ = check_total_derivative(P, gamma, d)
    assert t.min_rate > 1.9, t
    assert err < 1e-5, err


def test_dropping_the_blend_derivative_breaks_the_taylor_test(monkeypatch):
    """Teeth: without the g'(rho) term of S_rho the two-way gradient is first-order wrong."""
    def without_blend_derivative(self, u, rho, simp):
        g, _ = self.nonlinear_weight(rho)
        return self.kernel.density_vectors(np.asarray(u)[self.dofs], simp(rho), simp.derivative(rho), g, 0 * g)
    P = problem(*CASES["monolithic yeoh"], *WIDE)
    gamma, d = random_design(P, seed=2)
    monkeypatch.setattr(FiniteStrainElasticity, "density_vectors", without_blend_derivative)
    t, err, _ = check_total_derivative(P, gamma, d)
    assert t.rates[-1] < 1.5 and err > 1e-3, (t, err)          # rates fall towards 1


def test_check_gradients_command_on_a_coarse_two_way_scene(tmp_path, monkeypatch, capsys):
    """``tofsi check-gradients --set structure.model=neo-hookean`` passes on a coarse two-way scene
    (Yeoh mover, monolithic Newton) and fails (status 1) when S_rho is 1 % off."""
    import json
    from tofsi.cli import main
    from conftest import scene_path
    args = ["check-gradients", str(scene_path("beam_in_channel_optimization")), "--output", str(tmp_path),
            "--json", "-q", "--overwrite"]
    for key in ("mesh.h_min=0.1", "mesh.h_max=0.1", "effects.coupling=two-way", "mover.name=yeoh",
                "structure.youngs_modulus=1e4", "structure.load_exponent=3", "structure.model=neo-hookean"):
        args += ["--set", key]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["passed"] and {r["check"] for r in out["checks"]} >= {"S_u", "S_w", "S_x", "S_rho", "D_u",
                                                                      "objective compliance"}
    original = FiniteStrainElasticity.density_vectors
    monkeypatch.setattr(FiniteStrainElasticity, "density_vectors",
                        lambda self, u, rho, simp: 1.01 * original(self, u, rho, simp))
    assert main(args) == 1
    out = json.loads(capsys.readouterr().out)
    assert "S_rho" in {r["check"] for r in out["checks"] if not r["passed"]}


def test_a_resumed_finite_strain_optimization_reproduces_the_history_exactly(tmp_path):
    """Newton warm-starts from the previous design's state; the replay makes the same starts (E = 1e5:
    the gray start moves 0.36 m)."""
    from tofsi.optimization.optimize import Optimizer
    from conftest import scene_path
    overrides = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.25", "optimizer.max_iter=10",
                 "design.stage_iterations=6", "structure.model=neo-hookean", "structure.youngs_modulus=1e5",
                 "structure.load_exponent=3"]

    def run(output, on_iteration=None, resume=False):
        scene = tofsi.load_scene(scene_path("beam_in_channel_optimization"), overrides)
        opt = Optimizer(tofsi.Problem(scene), output, on_iteration=on_iteration)
        opt.run(resume=resume)
        return opt

    full = run(tmp_path / "full")

    def interrupt(it):
        if it.iteration == 7:                                 # inside the second stage
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "cut", on_iteration=interrupt)
    resumed = run(tmp_path / "cut", resume=True)
    key = lambda h: (h.iteration, h.stage, h.objective, h.volume, h.constraint, h.change, h.beta)
    assert [key(h) for h in resumed.history] == [key(h) for h in full.history]   # bitwise
    assert full.history[-1].objective < 0.5 * full.history[0].objective
