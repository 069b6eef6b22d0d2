"""Outside extensions through entry points, with no edit in the tree (issue 30's acceptance).

A small plugin distribution is written to a folder on ``PYTHONPATH`` (a package and its
``.dist-info`` with ``entry_points.txt``), beside a broken one whose entry points name a module
that does not exist. Through the command line, in fresh processes:

* an objective with a parameter (``[objective.pressure-norm] p``), a mover, and a field with
  its own table (``[tracer]``) and its own objective each pass ``tofsi check-gradients`` and
  run ``tofsi optimize``;
* the broken plugin leaves every scene that does not use it working, and a scene that names
  one of its entries exits 2 with one line naming the entry point.

The three runs through ``check-gradients`` and ``optimize`` are acceptance tests (``-m acceptance``).
"""

import json
import os
import subprocess
import sys
import textwrap

import pytest

from conftest import scene_path

COARSE = ["mesh.h_min=0.1", "mesh.h_max=0.1"]

OBJECTIVE = '''
    """An objective with a parameter: the p-norm of the corner pressures."""
    from dataclasses import dataclass

    import numpy as np

    from tofsi.core.config import option
    from tofsi.objectives import Objective


    @dataclass(frozen=True)
    class PressureNormParams:
        p: float = option(2.0, ge=1, le=64, doc="exponent of the norm")


    class PressureNorm(Objective):
        """``(sum_k |p_k|^p)^(1/p)`` over the corner pressures [Pa]."""

        name, needs, label, units = "pressure-norm", "w", "pressure p-norm", "Pa"
        Params = PressureNormParams

        def value(self, model, state):
            p = state.w[model.flow.n_velocity:]
            return float(np.sum(np.abs(p) ** self.params.p) ** (1.0 / self.params.p))

        def partials(self, model, state):
            q = self.params.p
            p = state.w[model.flow.n_velocity:]
            norm = np.sum(np.abs(p) ** q) ** (1.0 / q)
            g = np.zeros_like(state.w)
            g[model.flow.n_velocity:] = norm ** (1.0 - q) * np.abs(p) ** (q - 1.0) * np.sign(p)
            return {"w": g}
'''

MOVER = '''
    """A mover of its own: linear elasticity under another name."""
    from movers.linear import LinearElasticMover


    class DemoMover(LinearElasticMover):
        name = "demo-linear"
'''

TRACER = '''
    """A field with its own table and objective: ``c`` on the corner nodes, (L + I) c = gain P w."""
    from dataclasses import dataclass

    import numpy as np
    import scipy.sparse as sp

    from tofsi.core.blocks import FieldBlock, Linearization
    from tofsi.core.config import option
    from tofsi.fields.base import Field, Memory, on_q2_nodes
    from tofsi.linalg import DirectSolver
    from tofsi.objectives import Objective
    from tofsi.scene.tables import SceneTable


    @dataclass(frozen=True)
    class TracerSettings:
        enabled: bool = option(False, doc="solve the tracer")
        gain: float = option(1.0, gt=0, doc="source per unit pressure")


    class TracerBlock(FieldBlock):
        name, symbol, report_name, inputs = "c", "C", "", ("w",)
        fixed = np.array([], dtype=int)

        def __init__(self, mesh, flow, gain):
            self.size, self.flow = mesh.n_nodes, flow
            q = mesh.quads
            edges = np.vstack([q[:, [0, 1]], q[:, [1, 2]], q[:, [2, 3]], q[:, [3, 0]]])
            adj = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(self.size,) * 2)
            adj = ((adj + adj.T) > 0).astype(float)
            self.A = (sp.diags(np.asarray(adj.sum(axis=1)).ravel() + 1.0) - adj).tocsr()
            rows = np.arange(self.size)
            self.P = sp.csr_matrix((np.full(self.size, gain), (rows, flow.n_velocity + rows)),
                                   shape=(self.size, flow.size))

        def initial(self, fields, rho, params):
            return np.zeros(self.size)

        def residual(self, fields, rho, params):
            return self.A @ fields["c"] - self.P @ fields["w"]

        def linearize(self, fields, rho, params):
            return TracerLinearization(self, fields, rho, params)

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
        name, title, summary = "c", "tracer", ("tracer_mean",)
        tables = (SceneTable("tracer", TracerSettings),)

        def active(self, scene, command="solve"):
            return scene.tracer.enabled and scene.effects.fluid != "none" and command not in ("move", "tune")

        def memory(self, grid, scene):
            return Memory(grid.nodes, "q1-vector", 0.0)

        def build(self, model):
            return TracerBlock(model.mesh, model.flow, model.scene.tracer.gain)

        def block(self, model, stage):
            return model.physics["c"]

        def figures(self, model, state):
            return {"tracer_mean": float(state.fields["c"].mean())}

        def point_data(self, model, state):
            return {"tracer": on_q2_nodes(model.mesh, state.fields["c"])}


    FIELD = TracerField()


    class TracerEnergy(Objective):
        """``1/2 c . c`` of the tracer."""

        name, needs, label, units = "tracer-energy", "c", "tracer energy", "-"

        def value(self, model, state):
            c = state.fields["c"]
            return 0.5 * float(c @ c)

        def partials(self, model, state):
            return {"c": state.fields["c"].copy()}
'''

ENTRY_POINTS = {"tofsi_demo_plugins": """
    [tofsi.objectives]
    pressure-norm = tofsi_demo_plugins.objective:PressureNorm
    tracer-energy = tofsi_demo_plugins.tracer:TracerEnergy
    [tofsi.movers]
    demo-linear = tofsi_demo_plugins.mover:DemoMover
    [tofsi.fields]
    c = tofsi_demo_plugins.tracer:FIELD
""", "tofsi_broken_plugins": """
    [tofsi.objectives]
    broken-objective = tofsi_broken_missing.objective:Broken
    [tofsi.movers]
    broken-mover = tofsi_broken_missing.mover:Broken
    [tofsi.fields]
    broken-field = tofsi_broken_missing.field:FIELD
    [tofsi.materials]
    broken-material = tofsi_broken_missing.material:Broken
"""}


@pytest.fixture(scope="module")
def plugins(tmp_path_factory):
    """A folder with the two plugin distributions, and a runner of ``tofsi`` that sees them."""
    root = tmp_path_factory.mktemp("plugins")
    package = root / "tofsi_demo_plugins"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for module, text in (("objective", OBJECTIVE), ("mover", MOVER), ("tracer", TRACER)):
        (package / f"{module}.py").write_text(textwrap.dedent(text))
    for name, points in ENTRY_POINTS.items():
        info = root / f"{name}-0.1.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name.replace('_', '-')}\nVersion: 0.1\n")
        (info / "entry_points.txt").write_text(textwrap.dedent(points))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(root), os.environ.get("PYTHONPATH")) if p)}

    def run(*args, cwd=None):
        return subprocess.run([sys.executable, "-m", "tofsi.cli", *map(str, args)], capture_output=True,
                              text=True, env=env, cwd=cwd)

    def python(code):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
        assert done.returncode == 0, done.stderr
        return json.loads(done.stdout)
    run.python = python
    return run


def sets(*overrides):
    return [a for o in [*COARSE, *overrides] for a in ("--set", o)]


def check_and_optimize(plugins, tmp_path, scene, *overrides, stage=None):
    checked = plugins("check-gradients", scene_path(scene), *sets(*overrides), *(["--stage", stage] if stage else []),
                      "--output", tmp_path / "check", "--json")
    assert checked.returncode == 0, checked.stderr
    figures = json.loads(checked.stdout)
    assert figures["passed"], [r for r in figures["checks"] if not r["passed"]]
    optimized = plugins("optimize", scene_path(scene), *sets(*overrides, "optimizer.max_iter=2"),
                        "--output", tmp_path / "opt", "--json")
    assert optimized.returncode == 0, optimized.stderr
    assert json.loads(optimized.stdout)["iterations"] == 2
    return figures, tmp_path / "opt"


@pytest.mark.acceptance
def test_an_objective_with_a_parameter_from_an_entry_point(plugins, tmp_path):
    _, out = check_and_optimize(plugins, tmp_path, "double_pipe", "design.objective=pressure-norm",
                                "objective.pressure-norm.p=4")
    history = json.loads((out / "history.json").read_text())
    expected = plugins.python(textwrap.dedent(f"""
        import json, numpy as np, tofsi
        s = tofsi.load_scene({str(scene_path('double_pipe'))!r}, {[*COARSE, 'design.objective=pressure-norm',
                                                                  'objective.pressure-norm.p=4']!r})
        P = tofsi.Problem(s)
        p = P.solve(P.initial_design()).w[P.model.flow.n_velocity:]
        print(json.dumps([float(np.sum(p ** 4) ** 0.25), float(np.sqrt(p @ p)), s.objective.params['pressure-norm'].p]))
    """))
    four_norm, two_norm, p = expected
    assert p == 4.0 and history[0]["objective"] == pytest.approx(four_norm, rel=1e-9)   # the parameter's value
    assert abs(four_norm / two_norm - 1) > 1e-3
    record = json.loads((out / "run.json").read_text())
    assert "[objective.pressure-norm]" in record["scene"] and "p = 4.0" in record["scene"]


@pytest.mark.acceptance
def test_a_mover_from_an_entry_point(plugins, tmp_path):
    """Two-way from the first iteration (a stiffer structure than the scene's, so that the gray
    start moves the mesh by what a linear mover follows), the plugin's parameter table used."""
    figures, out = check_and_optimize(plugins, tmp_path, "beam_in_channel_optimization_fsi", "mover.name=demo-linear",
                                      "mover.demo-linear.chi=1", 'design.coupling=["two-way"]',
                                      "structure.youngs_modulus=1e6", stage="0")
    assert any(r["check"].startswith("D_") for r in figures["checks"])      # the mover's own blocks
    history = json.loads((out / "history.json").read_text())
    assert all(h["coupling"] == "two-way" and h["min_skewness"] < 1.0 for h in history)   # the mesh moved


@pytest.mark.acceptance
def test_a_field_with_its_own_table_and_objective_from_entry_points(plugins, tmp_path):
    figures, out = check_and_optimize(plugins, tmp_path, "double_pipe", "tracer.enabled=true", "tracer.gain=2.0",
                                      "design.objective=tracer-energy")
    assert any(r["check"].startswith("C_") for r in figures["checks"])      # the tracer's block
    record = json.loads((out / "run.json").read_text())
    assert "[tracer]" in record["scene"] and "gain = 2.0" in record["scene"]
    refused = plugins("optimize", scene_path("double_pipe"), *sets("design.objective=tracer-energy"),
                      "--output", tmp_path / "off")
    assert refused.returncode == 2 and "needs the field 'c'" in refused.stderr        # tracer.enabled = false


def test_a_broken_plugin_leaves_scenes_that_do_not_use_it_working(plugins, tmp_path):
    run = plugins("solve", scene_path("double_pipe"), *sets(), "--output", tmp_path / "ok", "--json")
    assert run.returncode == 0, run.stderr
    assert "broken-field = tofsi_broken_missing.field:FIELD" in run.stderr       # a warning, once
    moved = plugins("move", scene_path("foil_in_channel"), *sets(), "--output", tmp_path / "move", "--json")
    assert moved.returncode == 0, moved.stderr
    for key, name, group in (("design.objective", "broken-objective", "tofsi.objectives"),
                             ("mover.name", "broken-mover", "tofsi.movers"),
                             ("structure.model", "broken-material", "tofsi.materials")):
        scene = "beam_in_channel_optimization_fsi" if key == "mover.name" else "beam_in_channel_optimization"
        failed = plugins("solve", scene_path(scene), *sets(f"{key}={name}"), "--output", tmp_path / name)
        assert failed.returncode == 2, failed.stderr
        line = [ln for ln in failed.stderr.splitlines() if ln.startswith("tofsi: error:")]
        assert len(line) == 1 and f"{key} = '{name}'" in line[0] and f"group {group}" in line[0], failed.stderr
        assert "ModuleNotFoundError" in line[0] and "Traceback" not in failed.stderr


def test_the_reference_command_documents_the_installed_plugins(plugins, tmp_path):
    full = plugins("reference")
    assert full.returncode == 0, full.stderr
    assert "`objective.pressure-norm.p`" in full.stdout and "`tracer.gain`" in full.stdout
    assert "demo-linear" in full.stdout and "`tracer-energy`" in full.stdout
    builtin = plugins("reference", "--builtin")
    assert builtin.returncode == 0 and "pressure-norm" not in builtin.stdout and "tracer" not in builtin.stdout
    from tofsi.scene.scene import reference_table
    assert builtin.stdout == reference_table(builtin=True)
    doc = tmp_path / "doc.md"
    doc.write_text("intro\n<!-- generated by `tofsi reference --builtin`: begin -->\nold\n"
                   "<!-- generated by `tofsi reference --builtin`: end -->\nend\n")
    assert plugins("reference", "--builtin", "--update", doc).returncode == 0
    assert doc.read_text().split("\n", 2)[2].startswith(builtin.stdout) and doc.read_text().endswith("end\n")
