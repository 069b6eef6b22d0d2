"""Every kept evaluation refreshes when any of its inputs changes, and hands out read-only arrays.

For each kept value (the flow's element Jacobians, element residuals, shape derivatives and
force scale, the equal-order flow's element basis; the fluid load's element values, shape derivatives and stress operators; the mesh
motion's problem and blend; a design problem's point) the same object is asked again after one
input changed -- an array, the continuation record, the flow's density or its settings record --
and the answer must equal a fresh object's, built for the changed inputs alone.
"""

import dataclasses

import numpy as np
import pytest

import tofsi
from tofsi.core.blocks import Continuation, Stage
from tofsi.coupling.coupled import CoupledModel
from tofsi.physics.flow import Flow
from tofsi.physics.fluid_load import FluidForce

from conftest import load

SCENE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "effects.coupling=two-way", "mover.name=yeoh"]


@pytest.fixture(scope="module")
def point():
    """A two-way model, a solved state and a second point near it."""
    model = CoupledModel(load("beam_in_channel_optimization", *SCENE))
    rng = np.random.default_rng(7)
    rho = model.densities(rng.uniform(0.2, 0.8, model.design_elements.size))
    stage = model.stage.with_params(load_exponent=2.0)
    state = model.solve(rho, stage=stage)
    n = model.mesh.n_nodes
    x = state.x if state.x is not None else np.zeros(2 * n)
    x = x + 1e-3 * rng.normal(size=2 * n) * np.repeat(~np.isin(np.arange(n), model.mesh.boundary_nodes), 2)
    return {"model": model, "w": state.w, "x": x.reshape(-1, 2), "rho": rho, "params": stage.params,
            "rng": rng}


def variants(p):
    """``(what changed, inputs, change to the flow object)`` for every input."""
    base = {"w": p["w"], "x": p["x"], "rho": p["rho"], "params": p["params"]}
    rng = np.random.default_rng(11)
    return [("w", {**base, "w": p["w"] * (1 + 1e-3 * rng.normal(size=p["w"].size))}, None),
            ("x", {**base, "x": p["x"] * 1.5}, None),
            ("x absent", {**base, "x": None}, None),
            ("rho", {**base, "rho": np.clip(p["rho"] + 0.05, 0, 1)}, None),
            ("brinkman q", {**base, "params": dataclasses.replace(p["params"], brinkman_q=0.02)}, None),
            ("load exponent", {**base, "params": dataclasses.replace(p["params"], load_exponent=3.0)}, None),
            ("flow density", base, {"density": 0.5}),
            ("settings", base, {"settings": "viscosity"})]


def changed(flow: Flow, change):
    """Apply ``change`` to ``flow`` (its density attribute, or a new settings record)."""
    if change is None:
        return
    if "density" in change:
        flow.density = change["density"]
    else:
        flow.settings = dataclasses.replace(flow.settings, viscosity=2.0 * flow.settings.viscosity)


def fresh_flow(model, change) -> Flow:
    flow = Flow(model.mesh, model.scene.fluid)
    changed(flow, change)
    return flow


def same(a, b):
    if isinstance(a, tuple):
        assert len(a) == len(b)
        for u, v in zip(a, b, strict=True):
            same(u, v)
    elif a is None:
        assert b is None
    else:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def read_only(value):
    values = value if isinstance(value, tuple) else (value,)
    return all(not v.flags.writeable for v in values if isinstance(v, np.ndarray))


FLOW_KEPT = {"element Jacobians": lambda f, i: f.element_jacobians(i["w"], i["x"], i["rho"], i["params"]),
             "element residuals": lambda f, i: f.element_residuals(i["w"], i["x"], i["rho"], i["params"]),
             "shape derivatives": lambda f, i: f.shape_elements(i["w"], i["x"], i["rho"], i["params"]),
             "force scale": lambda f, i: f.residual_scale(i["x"], f.density)}


FLOW_BLIND = {"element Jacobians": {"load exponent"}, "element residuals": {"load exponent"},
              "shape derivatives": {"load exponent"},
              "force scale": {"w", "rho", "brinkman q", "load exponent"}}      # inputs a value does not read


def last_array(value):
    return np.ravel(np.asarray(value[-1] if isinstance(value, tuple) else value))


@pytest.mark.parametrize("kept", list(FLOW_KEPT))
def test_the_flows_kept_evaluations_refresh_on_every_input(kept, point):
    evaluate = FLOW_KEPT[kept]
    base = {"w": point["w"], "x": point["x"], "rho": point["rho"], "params": point["params"]}
    for what, inputs, change in variants(point):
        flow = fresh_flow(point["model"], None)
        first = evaluate(flow, base)
        assert kept == "force scale" or read_only(first), what
        changed(flow, change)
        again = evaluate(flow, inputs)
        same(again, evaluate(fresh_flow(point["model"], change), inputs))
        assert what in FLOW_BLIND[kept] or not np.array_equal(last_array(first), last_array(again)), what


LOAD_KEPT = {"element values": lambda f, i: f.elements(i["w"], i["x"], i["rho"], i["params"], partials=True),
             "element loads": lambda f, i: f.elements(i["w"], i["x"], i["rho"], i["params"])[0],
             "flow partials": lambda f, i: f.fluid_elements(i["w"], i["x"], i["rho"], i["params"]),
             "shape derivatives": lambda f, i: f.shape_elements(i["w"], i["x"], i["rho"], i["params"])}


@pytest.mark.parametrize("form", ["reaction", "stress-divergence"])
@pytest.mark.parametrize("kept", list(LOAD_KEPT))
def test_the_fluid_loads_kept_evaluations_refresh_on_every_input(kept, form, point):
    evaluate = LOAD_KEPT[kept]
    base = {"w": point["w"], "x": point["x"], "rho": point["rho"], "params": point["params"]}
    for what, inputs, change in variants(point):
        flow = fresh_flow(point["model"], None)
        force = FluidForce(flow, form)
        first = evaluate(force, base)
        assert read_only(first), what
        changed(flow, change)
        again = evaluate(force, inputs)
        same(again, evaluate(FluidForce(fresh_flow(point["model"], change), form), inputs))
        moved = not np.array_equal(np.asarray(first[0] if isinstance(first, tuple) else first),
                                   np.asarray(again[0] if isinstance(again, tuple) else again))
        blind = (form == "stress-divergence"            # not an input of it (the load is linear in w)
                 and (what in ("brinkman q", "flow density") or (kept == "flow partials" and what == "w")))
        assert moved or blind, what


def test_the_stress_operators_refresh_with_the_mesh_and_the_viscosity(point):
    flow = fresh_flow(point["model"], None)
    force = FluidForce(flow, "stress-divergence")
    first = force.stress_operators(point["x"])
    assert read_only(first)
    for x, change in ((None, None), (1.5 * point["x"], None), (point["x"], {"settings": "viscosity"})):
        changed(flow, change)
        again = force.stress_operators(x)
        same(again, FluidForce(fresh_flow(point["model"], change), "stress-divergence").stress_operators(x))
        assert not np.array_equal(first, again)
        first = again


def test_the_mesh_motions_problem_and_blend_refresh_with_the_densities(point):
    model = point["model"]
    motion = model.motion
    rho2 = np.clip(point["rho"] + 0.1, 0, 1)
    fresh = CoupledModel(model.scene).motion
    for rho in (point["rho"], rho2, point["rho"]):
        problem = motion.problem(rho)
        np.testing.assert_array_equal(problem.blend, fresh.problem(rho).blend)
        np.testing.assert_array_equal(problem.stiffening, fresh.problem(rho).stiffening)
        x = point["x"].ravel()
        u = np.zeros_like(x)
        same(motion.residual(x, u, rho, jacobian=False)[0], fresh.residual(x, u, rho, jacobian=False)[0])
    assert not np.array_equal(motion.problem(point["rho"]).blend, motion.problem(rho2).blend)


def test_a_design_problems_point_refreshes_with_the_design_and_the_stage(point):
    scene = load("beam_in_channel_optimization", "mesh.h_min=0.1", "mesh.h_max=0.1")
    problem = tofsi.Problem(scene)
    gamma = problem.initial_design()
    f = problem.evaluate(gamma)[0]
    assert problem.evaluate(gamma)[0] == f and problem.evaluations == 1     # the kept point
    other = np.clip(gamma + 0.05, 0, 1)
    for make in (lambda: (other, problem.stage),
                 lambda: (gamma, problem.stage.with_params(penalty=2.0)),
                 lambda: (gamma, problem.stage.with_params(beta=4.0))):
        g, stage = make()
        problem.set_stage(stage)
        fresh = tofsi.Problem(scene)
        fresh.set_stage(stage)
        assert problem.evaluate(g)[0] == pytest.approx(fresh.evaluate(g)[0], rel=1e-9)
        problem.set_stage(Stage(Continuation(**dataclasses.asdict(problem.params))))   # equal, not the same
    assert problem.evaluations == 4


def test_the_equal_order_flows_kept_basis_refreshes_with_the_configuration(point):
    """The Q1/Q1 flow keeps its element basis per configuration (keyed by ``x``, read-only; no
    process-wide cache): a moved or unmoved mesh gives a fresh flow's basis, and the kernel with
    the kept basis gives the values it forms with its own. Taylor-Hood keeps none."""
    model, x = point["model"], point["x"]
    settings = dataclasses.replace(model.scene.fluid, element="q1q1")
    flow = Flow(model.mesh, settings)
    first = flow.basis(x)
    assert read_only(first) and flow.basis(x) is first
    for moved in (1.5 * x, None):
        again = flow.basis(moved)
        same(again, Flow(model.mesh, settings).basis(moved))
        assert not np.array_equal(first[1], again[1])
    w = np.random.default_rng(3).normal(size=flow.size)
    kept = flow.element_residual(w, x, point["rho"], params=point["params"])             # the kept basis
    formed = flow.element_residual(w, x, point["rho"], Xe=flow.corners(x), params=point["params"])
    same(kept, formed)
    assert Flow(model.mesh, model.scene.fluid).basis(x) is None
