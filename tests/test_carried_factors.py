"""The block factors a design's two-way solve carries into the next design's Newton.

Truths: the factors are a function of what they were factorized from, so made again from the
recorded key (the points of their blocks) they precondition bit for bit as the carried ones do,
and from a key one bit off they do not (teeth); they are refused at another stage (projection
sharpness, structure model) and where a block's point is unknown; the next design's solve uses
them (no new flow factorization) and reaches the state a fresh solve reaches to the Newton's
tolerance; a run cut inside a two-way stage and resumed writes the uninterrupted files bitwise.
"""

import json

import numpy as np
import pytest

import tofsi
from tofsi.core.blocks import Stage
from tofsi.coupling.coupled import continuation
from tofsi.coupling.jacobian_point import JacobianPoint
from tofsi.linalg import BlockGaussSeidel
from tofsi.optimization.carried_factors import CarriedFactors, restore
from tofsi.optimization.optimize import Optimizer

from conftest import load

COARSE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.25"]
TWO_WAY = 3                            # the large scene's first two-way stage


@pytest.fixture(scope="module")
def solved():
    """The large scene's first two-way stage at 20 x 10: a design solved, its adjoint taken."""
    scene = load("beam_in_channel_optimization_large", "mesh.h_min=0.1", "mesh.h_max=0.1",
                 "design.filter_radius=0.2")
    problem = tofsi.Problem(scene)
    problem.set_stage(continuation(scene, TWO_WAY))
    c = problem.model.mesh.centroids[problem.map.design]
    gamma = np.where((np.abs(c[:, 0] - 1.0) < 0.2) & (c[:, 1] < 0.55), 1.0, 0.0)     # a post: moves ~0.19 m
    problem.evaluate(gamma)
    return problem, gamma


def sweep(pre: BlockGaussSeidel, n: int) -> np.ndarray:
    """The preconditioner applied to a fixed vector, both ways."""
    r = np.cos(np.arange(n) * 0.37)
    return np.concatenate([pre.preconditioner(False)(r), pre.preconditioner(True)(r)])


def test_factors_made_again_from_their_key_precondition_bitwise(solved):
    problem, _ = solved
    factors = problem.factors
    table, arrays = factors.record()
    assert all(isinstance(o, JacobianPoint) for o in factors.preconditioner().origins)
    system = problem.model.system_for(problem.stage)
    again = restore(json.loads(json.dumps(table)), arrays, problem.stage, system)
    n = factors.preconditioner().shape[0]
    np.testing.assert_array_equal(sweep(again.preconditioner(), n), sweep(factors.preconditioner(), n))
    assert again.solver.fresh_cost == factors.solver.fresh_cost
    off = {k: (v * (1 + 1e-12) if k.endswith("_field_w") else v) for k, v in arrays.items()}   # teeth
    other = restore(table, off, problem.stage, system)
    assert not np.array_equal(sweep(other.preconditioner(), n), sweep(factors.preconditioner(), n))


def test_factors_are_refused_at_another_stage_or_without_their_points(solved):
    problem, _ = solved
    factors, stage = problem.factors, problem.stage
    assert factors.for_stage(stage) is not None
    assert factors.for_stage(stage.with_params(beta=2 * stage.params.beta)) is None
    assert factors.for_stage(Stage(stage.params, stage.coupling, "linear")) is None
    pre = factors.preconditioner()
    unnamed = BlockGaussSeidel(pre.A.tocsr(), sizes=pre.A.sizes)      # assembled: no origin
    solver = problem.model.system_for(stage).linear_solver(factors.comp)
    solver.solver = unnamed
    assert CarriedFactors(stage, factors.comp, solver).for_stage(stage) is None
    assert CarriedFactors(stage, factors.comp, solver).record() is None


def test_the_next_design_starts_from_the_carried_factors_and_reaches_the_fresh_state(solved):
    problem, gamma = solved
    nearby = np.clip(gamma + 0.002 * np.sin(np.arange(gamma.size)), 0, 1)
    guess = problem.point(gamma).state.data()
    carried = problem.factors
    state = problem.solve(nearby)
    solver = state.coupled[carried.comp].solver
    assert solver.factorizations == 0 and solver.solver is carried.preconditioner()
    fresh = problem.model.solve(problem.densities(nearby), guess, stage=problem.stage)
    assert fresh.coupled[carried.comp].solver.factorizations >= 1
    for f in ("w", "u", "x"):
        ref = fresh.fields[f]
        assert np.abs(state.fields[f] - ref).max() <= 1e-7 * np.abs(ref).max()


FSI = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.coupling=[]", "design.filter_radius=0.25",
       "structure.youngs_modulus=1e5", "design.stage_iterations=4", "optimizer.max_iter=8",
       "optimizer.output_every=100"]      # two-way from the first design, 4 designs a stage


def files(output) -> tuple:
    """history.json without its times, design.npy, final_state.npz."""
    rows = json.loads((output / "history.json").read_text())
    for row in rows:
        row.pop("time_s")
    with np.load(output / "final_state.npz") as final:
        state = {k: final[k] for k in final.files}
    return rows, np.load(output / "design.npy"), state


@pytest.mark.parametrize("restored", [True, False])
def test_a_run_cut_inside_a_two_way_stage_resumes_to_the_uninterrupted_files_bitwise(tmp_path, monkeypatch,
                                                                                     restored):
    """Cut after the second design of the first two-way stage; the resume makes the factors again
    from the checkpoint's key. Teeth: a resume that starts the next Newton from fresh factors
    instead ends elsewhere in the last bits."""
    def run(output, on_iteration=None, resume=False):
        opt = Optimizer(tofsi.Problem(load("beam_in_channel_optimization_fsi", *FSI)), output,
                        on_iteration=on_iteration)
        opt.run(resume=resume)
        return opt

    full = run(tmp_path / "full")
    assert [h.coupling for h in full.history] == ["two-way"] * 8

    def interrupt(it):
        if it.iteration == 1:                                # inside the first two-way stage
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "cut", on_iteration=interrupt)
    with np.load(tmp_path / "cut" / "checkpoint.npz") as checkpoint:
        assert json.loads(str(checkpoint["meta"]))["factors"] is not None   # the next solve's, by their key
    if not restored:
        monkeypatch.setattr(tofsi.Problem, "resume_factors", lambda self, *key: None)
    run(tmp_path / "cut", resume=True)
    (rows, design, state), (rows0, design0, state0) = files(tmp_path / "cut"), files(tmp_path / "full")
    same = (rows == rows0 and np.array_equal(design, design0) and state.keys() == state0.keys()
            and all(np.array_equal(state[k], state0[k]) for k in state))
    assert same == restored
