"""Hard cases stay numerically stable: valid meshes or a clear failure, never silent garbage."""

import json
import subprocess
import sys

import numpy as np
import pytest

import movers
import tofsi
from movers.base import MotionProblem
from tofsi.mesh import quality
from tofsi.core.errors import NumericalError
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.coupling.motion import run_move

from conftest import load, scene_path


def move_or_fail(scene):
    """(displacement, None) for a valid mesh, or (None, diagnostic) for a reported failure."""
    try:
        setup, result = run_move(scene)
    except NumericalError as err:
        return setup_of(scene), None, err.diagnostic
    return setup, result, None


def setup_of(scene):
    from tofsi.coupling.motion import motion_setup
    return motion_setup(scene)


@pytest.mark.parametrize("mover", ["yeoh", "spring"])
@pytest.mark.parametrize("motion", ["deformation.mode=rotation deformation.rotation_deg=60",
                                    "deformation.mode=translation deformation.translation=0.375"],
                         ids=["rotation 60 deg", "translation to two elements from the wall"])
def test_large_foil_motions_give_a_valid_mesh_or_a_diagnostic(mover, motion):
    scene = load("foil_in_channel", f"mover.name={mover}", *motion.split())
    setup, result, diagnostic = move_or_fail(scene)
    if result is not None:
        moved = setup.mesh.points + result.displacement
        assert not quality.inverted(moved, setup.mesh.quads[setup.moving]).any()
        assert result.report.converged and np.all(np.isfinite(result.displacement))
    else:
        q = diagnostic["quality"]
        assert "worst_element" in q and "worst_location" in q and not diagnostic["report"]["converged"]


@pytest.mark.parametrize("mover", ["yeoh", "spring"])
def test_cli_never_reports_success_with_an_inverted_mesh(mover, tmp_path):
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "move", str(scene_path("foil_in_channel")),
                          "--set", f"mover.name={mover}", "--set", "deformation.mode=rotation",
                          "--set", "deformation.rotation_deg=60", "--output", str(tmp_path), "--json"],
                         capture_output=True, text=True)
    assert run.returncode in (0, 3), run.stderr
    figures = json.loads(run.stdout)
    if run.returncode == 0:
        assert figures["n_inverted"] == 0 and figures["converged"]
    else:
        assert (tmp_path / "diagnostic.json").is_file() and not figures["converged"]


def test_an_oversized_single_spring_increment_is_reported_not_hidden():
    scene = load("foil_in_channel", "mover.name=spring", "mover.spring.increments=1",
                 "deformation.mode=rotation", "deformation.rotation_deg=60")
    with pytest.raises(NumericalError) as err:
        run_move(scene)
    assert err.value.diagnostic["quality"]["n_inverted"] > 0


def test_an_oversized_first_yeoh_increment_is_cut_back_on_the_foil():
    scene = load("foil_in_channel", "mover.name=yeoh", "mover.yeoh.increments=1",
                 "deformation.mode=rotation", "deformation.rotation_deg=45")
    _, result = run_move(scene)
    assert result.report.cutbacks >= 1 and result.report.converged


def boundary_layer_problem():
    """Cells 1e-4 high and 1e-2 wide at the floor (aspect ratio 100), a block moved by 1e-6."""
    ys = np.concatenate([np.arange(0, 21) * 1e-4, np.geomspace(2.2e-3, 0.1, 20)])
    xs = np.linspace(0, 0.4, 41)
    mesh = StructuredQuadMesh(xs, ys)
    block = np.flatnonzero((np.abs(mesh.centroids[:, 0] - 0.2) < 0.05) & (mesh.centroids[:, 1] > 0.03)
                           & (mesh.centroids[:, 1] < 0.06))
    moving = np.setdiff1d(np.arange(mesh.n_elements), block)
    boundary = np.unique(np.concatenate([mesh.side_nodes(s) for s in ("left", "right", "bottom", "top")]))
    fixed = np.union1d(boundary, np.unique(mesh.quads[block]))
    u = np.zeros((mesh.n_nodes, 2))
    u[np.unique(mesh.quads[block])] = [1e-6, -1e-6]
    h = np.diff(ys)
    assert np.max(np.diff(xs)[0] / h) == pytest.approx(100.0)
    return mesh, MotionProblem.from_mesh(mesh, moving, fixed), u


@pytest.mark.parametrize("mover", ["yeoh", "spring", "linear"])
def test_boundary_layer_mesh_with_aspect_ratio_100_under_a_tiny_motion(mover):
    mesh, problem, u = boundary_layer_problem()
    result = movers.create(mover).move(problem, u)
    x = result.displacement
    assert result.report.converged and np.all(np.isfinite(x))
    assert np.abs(x).max() <= 1e-6 * (1 + 1e-9)                 # a maximum principle holds here
    skew = quality.skewness(mesh.points + x, mesh.quads)
    assert skew.min() > 0.999


@pytest.mark.parametrize("alpha_max", [1e2, 1e5, 1e9])
def test_gradients_still_pass_with_extreme_brinkman_and_0_1_densities(alpha_max):
    from adjoint.checks import central_difference, relative_error, taylor_test
    scene = load("beam_in_channel_optimization", "mesh.h_min=0.1", "mesh.h_max=0.1",
                 f"fluid.alpha_max={alpha_max}", "fluid.newton_tol=1e-13", "design.filter_radius=0.01",
                 "design.beta=[0.0]", "design.objective=dissipation")
    P = tofsi.Problem(scene)
    c = P.model.mesh.centroids[P.map.design]
    gamma = ((np.abs(c[:, 0] - 1.0) < 0.25) & (c[:, 1] < 0.45)).astype(float)
    d = np.where(gamma > 0.5, -1.0, 1.0) * np.random.default_rng(0).uniform(0.2, 1, gamma.size)
    f0, df = P.evaluate(gamma)
    assert np.all(np.isfinite(df)) and np.isfinite(f0)
    state = P.solve(gamma)
    v = state.w[:P.model.flow.n_velocity].reshape(-1, 2)
    solid_nodes = np.ones(P.model.mesh.n_nodes9, bool)
    solid_nodes[P.model.mesh.quads9[state.rho < 1].ravel()] = False
    if alpha_max >= 1e9:
        assert np.abs(v[solid_nodes]).max() < 1e-5 * scene.fluid.inlet_velocity
    # friction alpha'(0) ~ alpha_max q makes f curved like alpha_max near void: scale the steps
    eps0 = min(1e-3, 1e2 / alpha_max)
    h = 1e-3 * eps0
    fun = lambda g: P.evaluate(g)[0]
    t = taylor_test(fun, gamma, df, d, eps0=eps0, steps=4, f0=f0)
    err = relative_error(central_difference(fun, gamma, d, h), df @ d)
    assert t.min_rate > 1.9 and err < 1e-5, (t, err)
