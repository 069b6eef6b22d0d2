"""Contract tests over every registry entry, and entries defined in this file alone.

* every objective optimizes through the command line to exit 0 with its pictures, and an
  objective defined here (one class) does too, with the value it defines;
* every scene table is written whole into provenance (its documented keys are its written
  keys) and round-trips through ``run.json``;
* every field's figures and arrays appear in ``solve.json`` and the VTU, its pictures on disk;
* a field defined here (physics, block and entry) appears in provenance, ``solve.json``, the
  VTU and the memory estimate, with the value it defines, and no file of tofsi was edited.
"""

import json
import tomllib
from dataclasses import dataclass

import meshio
import numpy as np
import pytest
import scipy.sparse as sp

import tofsi
from tofsi.runs import memory
from tofsi.core.blocks import FieldBlock, Linearization
from tofsi.core.config import option
from tofsi.fields.base import Field, Memory, Picture, on_q2_nodes
from tofsi.linalg import DirectSolver
from tofsi.objectives import Objective
from tofsi.runs.provenance import flatten, scene_tables
from tofsi.core.registry import FIELDS, OBJECTIVES
from tofsi.scene.scene import scene_from_dict, table_entries
from tofsi.scene.tables import SceneTable

from conftest import scene_path

COARSE = ["--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1"]
SCENE_FOR = {"structure": "beam_in_channel_optimization", "fluid": "double_pipe"}


def optimize(cli, tmp_path, objective, iterations=2):
    scene = SCENE_FOR[OBJECTIVES.get(objective).needs]
    run = cli("optimize", scene_path(scene), *COARSE, "--set", f"design.objective={objective}",
              "--set", f"optimizer.max_iter={iterations}", "--set", "optimizer.output_every=1",
              "--output", tmp_path / objective, "--json")
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout), tmp_path / objective


# ---- objectives ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", OBJECTIVES.names())
def test_every_objective_optimizes_through_the_command_line_with_its_pictures(name, cli, tmp_path):
    figures, out = optimize(cli, tmp_path, name)
    assert figures["iterations"] == 2 and np.isfinite(figures["objective"])
    for picture in ("convergence.png", "design_0000.png", "design_0001.png", "design_final.png"):
        assert (out / picture).stat().st_size > 1000, picture
    history = json.loads((out / "history.json").read_text())
    assert len(history) == 2 and all(np.isfinite(h["objective"]) for h in history)


class PressureEnergy(Objective):
    """``1/2 sum_k p_k^2`` over the corner pressures [Pa^2]: defined here and nowhere else."""

    name, needs, label, units = "pressure-energy", "fluid", "pressure energy", "Pa^2"

    def value(self, model, state):
        p = state.w[model.flow.n_velocity:]
        return 0.5 * float(p @ p)

    def partials(self, model, state):
        g = np.zeros_like(state.w)
        g[model.flow.n_velocity:] = state.w[model.flow.n_velocity:]
        return {"w": g}


@pytest.fixture
def pressure_energy():
    OBJECTIVES.register(PressureEnergy)
    yield PressureEnergy
    OBJECTIVES.unregister(PressureEnergy.name)


def test_an_objective_defined_in_a_test_file_optimizes_through_the_command_line(pressure_energy, cli,
                                                                                 tmp_path):
    assert "pressure-energy" in OBJECTIVES.names()
    figures, out = optimize(cli, tmp_path, "pressure-energy", iterations=3)
    history = json.loads((out / "history.json").read_text())
    scene = tofsi.load_scene(scene_path("double_pipe"), ["mesh.h_min=0.1", "mesh.h_max=0.1",
                                                         "design.objective=pressure-energy"])
    problem = tofsi.Problem(scene)                     # the value it defines, at the start
    state = problem.solve(problem.initial_design())
    p = state.w[problem.model.flow.n_velocity:]
    assert history[0]["objective"] == pytest.approx(0.5 * p @ p, rel=1e-9)
    assert history[-1]["objective"] < history[0]["objective"]       # the optimizer lowered it
    assert "pressure-energy" in tofsi.scene.scene.reference_table()


# ---- scene tables ----------------------------------------------------------------------------
@pytest.mark.parametrize("table", [t.name for t in table_entries()])
def test_every_scene_table_is_written_whole_into_provenance(table):
    """The keys the scene reference documents for a table are exactly the keys provenance writes
    for it (a table missing from provenance, or a key, fails here)."""
    scene = tofsi.load_scene(scene_path("beam_in_channel_optimization_fsi"))
    written = set(flatten({table: scene_tables(scene)[table]}))
    documented = {row[0] for row in next(t for t in table_entries() if t.name == table).rows()}
    assert written == documented


def test_a_solver_table_round_trips_through_run_json(cli, tmp_path):
    """The [solver] table was missing from provenance: scene_from_dict(scene_tables(s)) != s."""
    overrides = ["solver.blas_threads=2", "solver.max_memory_gb=20.0", "tune.layers=5", "coupled.tol=1e-8"]
    args = [a for o in overrides for a in ("--set", o)]
    run = cli("mesh", scene_path("double_pipe"), *args, "--output", tmp_path / "m")
    assert run.returncode == 0, run.stderr
    record = json.loads((tmp_path / "m" / "run.json").read_text())
    expected = tofsi.load_scene(scene_path("double_pipe"), overrides)
    again = scene_from_dict(tomllib.loads(record["scene"]), source=expected.source)
    assert again == expected and again.solver.blas_threads == 2
    assert tomllib.loads(record["scene"])["solver"]["max_memory_gb"] == 20.0


# ---- fields ----------------------------------------------------------------------------------
def test_every_field_writes_its_figures_arrays_and_pictures(cli, tmp_path):
    run = cli("solve", scene_path("beam_in_channel_optimization"), *COARSE, "--set", "effects.coupling=two-way",
              "--set", "mover.name=yeoh", "--set", "design.coupling=[\"two-way\"]", "--output", tmp_path / "s",
              "--json")
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    scene = tofsi.load_scene(scene_path("beam_in_channel_optimization"),
                             ["mesh.h_min=0.1", "mesh.h_max=0.1", "effects.coupling=two-way", "mover.name=yeoh"])
    model = tofsi.Problem(scene).model
    assert [f.name for f in model.fields] == list(FIELDS.names())       # every registered field
    state = model.solve(model.densities(), params=model.params)
    vtu = meshio.read(tmp_path / "s" / "solution.vtu")
    settings = json.loads((tmp_path / "s" / "solve.json").read_text())["settings"]
    for field in model.fields:
        assert set(field.figures(model, state)) <= set(figures), field.name
        assert set(field.point_data(model, state)) <= set(vtu.point_data), field.name
        for picture in field.pictures(model, state):
            assert (tmp_path / "s" / f"solution_{picture.name}.png").stat().st_size > 1000
        assert {table.name for table in field.tables} <= set(settings), field.name


@dataclass(frozen=True)
class TracerSettings:
    """A test field's scene table ``[tracer]``."""

    enabled: bool = option(False, doc="solve the tracer")
    gain: float = option(1.0, gt=0, doc="source per unit pressure")


class TracerBlock(FieldBlock):
    """``c`` on the corner nodes: ``(L + I) c = gain P w`` (``L`` the graph Laplacian of the mesh
    edges, ``P`` the corner pressures of the flow)."""

    name, symbol, report_name = "c", "C", ""
    inputs = ("w",)

    def __init__(self, mesh, flow, gain):
        self.size, self.flow, self.gain = mesh.n_nodes, flow, gain
        q = mesh.quads
        edges = np.vstack([q[:, [0, 1]], q[:, [1, 2]], q[:, [2, 3]], q[:, [3, 0]]])
        adj = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(self.size,) * 2)
        adj = ((adj + adj.T) > 0).astype(float)
        self.A = (sp.diags(np.asarray(adj.sum(axis=1)).ravel() + 1.0) - adj).tocsr()
        n_v = flow.n_velocity
        self.P = sp.csr_matrix((np.full(self.size, gain), (np.arange(self.size), n_v + np.arange(self.size))),
                               shape=(self.size, flow.size))

    fixed = np.array([], dtype=int)

    def initial(self, fields, rho, params):
        return np.zeros(self.size)

    def residual(self, fields, rho, params):
        return self.A @ fields["c"] - self.P @ fields["w"]

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None):
        c = DirectSolver(self.A).solve(self.P @ fields["w"])
        return c, TracerLinearization(self, {**fields, "c": c}, rho, params), None


class TracerLinearization(Linearization):
    def matrix(self):
        return self.block.A

    def solve(self, b):
        return DirectSolver(self.block.A).solve(b)

    def solve_transpose(self, b):
        return DirectSolver(self.block.A).solve_transpose(b)

    def coupling(self, other):
        return -self.block.P if other == "w" else None


class TracerField(Field):
    name, title, tables, summary = "c", "tracer", (SceneTable("tracer", TracerSettings),), ("tracer_mean",)

    def active(self, scene, command="solve"):
        return scene.tracer.enabled and scene.effects.fluid != "none" and command not in ("move", "tune")

    def memory(self, grid, scene):
        return Memory(grid.nodes, "q1-vector", 0.0)

    def build(self, model):
        return TracerBlock(model.mesh, model.flow, model.scene.tracer.gain)

    def block(self, model, two_way):
        return model.physics["c"]

    def figures(self, model, state):
        return {"tracer_mean": float(state.fields["c"].mean())}

    def point_data(self, model, state):
        return {"tracer": on_q2_nodes(model.mesh, state.fields["c"])}

    def pictures(self, model, state):
        return [Picture("tracer", "tracer", "c [-]", state.fields["c"])]


@pytest.fixture
def tracer():
    """The field and its own table, registered as a plugin module would: the field alone."""
    field = TracerField()
    FIELDS.register(field)
    yield field
    FIELDS.unregister(field.name)


def test_a_field_defined_in_a_test_file_reaches_provenance_solve_json_the_vtu_and_the_memory_guard(
        tracer, cli, tmp_path):
    overrides = ["mesh.h_min=0.1", "mesh.h_max=0.1", "tracer.enabled=true", "tracer.gain=2.0"]
    run = cli("solve", scene_path("beam_in_channel_optimization"), *[a for o in overrides for a in ("--set", o)],
              "--output", tmp_path / "s", "--json")
    assert run.returncode == 0, run.stderr
    out = tmp_path / "s"
    scene = tofsi.load_scene(scene_path("beam_in_channel_optimization"), overrides)
    problem = tofsi.Problem(scene)                     # solve's design: the uniform one, as optimize maps it
    model, state = problem.model, problem.solve(problem.initial_design())
    p = state.w[model.flow.n_velocity:]
    c = np.linalg.solve(model.physics["c"].A.toarray(), 2.0 * p)        # the value it defines
    assert json.loads(run.stdout)["tracer_mean"] == pytest.approx(c.mean(), rel=1e-9)
    solve = json.loads((out / "solve.json").read_text())
    assert solve["figures"]["tracer_mean"] == pytest.approx(c.mean(), rel=1e-9)
    assert solve["settings"]["tracer"] == {"enabled": True, "gain": 2.0}
    record = json.loads((out / "run.json").read_text())
    assert tomllib.loads(record["scene"])["tracer"] == {"enabled": True, "gain": 2.0}
    assert scene_from_dict(tomllib.loads(record["scene"]), source=scene.source) == scene
    vtu = meshio.read(out / "solution.vtu")
    np.testing.assert_allclose(vtu.point_data["tracer"][:model.mesh.n_nodes], c, rtol=1e-9,
                               atol=1e-12 * np.abs(c).max())
    assert (out / "solution_tracer.png").stat().st_size > 1000
    estimate = memory.estimate(scene, "solve")
    assert estimate.unknowns["tracer"] == model.mesh.n_nodes
    assert "tracer" not in memory.estimate(tofsi.load_scene(scene_path("beam_in_channel_optimization")),
                                           "solve").unknowns
    assert "tracer.gain" in tofsi.scene.scene.reference_table()
