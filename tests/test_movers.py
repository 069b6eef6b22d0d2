"""Behaviour every mover shares, the registry, and ``tofsi move``."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import movers
from movers.base import MotionProblem
from reference_kernels import elastic_quad
from tofsi.mesh import quality
from tofsi.core.errors import InputError, NumericalError
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.coupling.motion import motion_setup, run_move
from tofsi.fem.elasticity import element_stiffness, lame

from conftest import load, scene_path

MOVERS = ["linear", "spring", "yeoh"]


def _annulus_like(n=8):
    """A graded square mesh with a fixed inner block (a 'structure') and a fixed outer boundary."""
    s = np.linspace(0, 1, n + 1)
    mesh = StructuredQuadMesh(s + 0.04 * np.sin(2 * np.pi * s), s**1.15)
    inner = np.flatnonzero((np.abs(mesh.centroids - 0.5) < 0.2).all(axis=1))
    moving = np.setdiff1d(np.arange(mesh.n_elements), inner)
    boundary = np.unique(np.concatenate([mesh.side_nodes(s) for s in ("left", "right", "bottom", "top")]))
    fixed = np.union1d(boundary, np.unique(mesh.quads[inner]))
    return mesh, MotionProblem.from_mesh(mesh, moving, fixed)


def rotation(points, degrees, centre=(0.5, 0.5)):
    t = np.radians(degrees)
    R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    rel = points - centre
    return rel @ R.T - rel


@pytest.mark.parametrize("name", MOVERS)
def test_zero_motion_gives_zero_mesh_motion(name):
    mesh, problem = _annulus_like()
    result = movers.create(name).move(problem, np.zeros((mesh.n_nodes, 2)))
    assert np.all(result.displacement == 0.0) and result.report.converged


@pytest.mark.parametrize("name", MOVERS)
def test_rigid_translation_of_every_fixed_node_translates_the_mesh(name):
    mesh, problem = _annulus_like()
    t = np.array([0.3, -0.17])
    result = movers.create(name).move(problem, np.tile(t, (mesh.n_nodes, 1)))
    np.testing.assert_allclose(result.displacement, np.tile(t, (mesh.n_nodes, 1)), atol=1e-12)


def test_rigid_rotation_is_rigid_for_the_hyperelastic_mover():
    mesh, problem = _annulus_like()
    u = rotation(mesh.points, 40.0)
    result = movers.create("yeoh", increments=4, newton_tol=1e-12).move(problem, u)
    moved = mesh.points + result.displacement
    np.testing.assert_allclose(quality.skewness(moved, mesh.quads), 1.0, atol=1e-8)
    np.testing.assert_allclose(result.displacement, u, atol=1e-9)


@pytest.mark.parametrize("increments", [1, 7])
def test_linear_mover_rotates_rigidly_because_q1_reproduces_affine_fields(increments):
    """Each increment of a rigid boundary rotation is an affine field: the patch test makes it exact."""
    mesh, problem = _annulus_like()
    u = rotation(mesh.points, 40.0)
    result = movers.create("linear", increments=increments).move(problem, u)
    np.testing.assert_allclose(result.displacement, u, atol=1e-12)


@pytest.mark.parametrize("diagonals", ["1-3", "both"])
def test_spring_mover_approaches_the_rigid_rotation_at_first_order(diagonals):
    """Linearized torsion errs by O(theta^2 / N) on an irregular mesh: doubling N halves the error."""
    mesh, problem = _annulus_like()
    u = rotation(mesh.points, 40.0)
    err = [np.abs(movers.create("spring", increments=n, diagonals=diagonals).move(problem, u)
                  .displacement - u).max() for n in (16, 32, 64)]
    rates = np.log2(np.array(err[:-1]) / err[1:])
    assert err[0] > 1e-6 and np.all(np.abs(rates - 1.0) < 0.1), (err, rates)


@pytest.mark.parametrize("diagonals", ["1-3", "both"])
def test_spring_mover_with_midpoint_stiffness_approaches_the_rigid_rotation_at_second_order(diagonals):
    """Each increment's stiffness at its midpoint extrapolated from the increment before: the
    error of the rigid rotation falls like 1/N^2 (doubling N quarters it), and 4 such increments
    are nearer the rotation than 10 at each increment's start (the large scene's trade)."""
    mesh, problem = _annulus_like()
    u = rotation(mesh.points, 40.0)

    def error(n, scheme):
        return np.abs(movers.create("spring", increments=n, diagonals=diagonals, scheme=scheme)
                      .move(problem, u).displacement - u).max()

    err = [error(n, "midpoint") for n in (8, 16, 32)]
    rates = np.log2(np.array(err[:-1]) / err[1:])
    assert err[0] > 1e-8 and np.all(np.abs(rates - 2.0) < 0.1), (err, rates)
    assert error(4, "midpoint") < error(10, "euler")


@pytest.mark.parametrize("diagonals", ["1-3", "both"])
def test_a_small_first_midpoint_increment_keeps_the_rigid_rotation_second_order(diagonals):
    """The midpoint scheme's first increment takes its stiffness at its start (nothing before it
    to extrapolate from): its error is first order. With the first increment's share shrinking
    like the others' (0.3/N) the rotation's error again falls like 1/N^2, and 3 increments with a
    first of 0.1 (the large scene's) are nearer the rotation than 3 equal ones (2026-11-28: 1.1e-5
    and 7.9e-6 against 1.6e-5 and 9.7e-6)."""
    mesh, problem = _annulus_like()
    u = rotation(mesh.points, 40.0)

    def error(n, first):
        return np.abs(movers.create("spring", increments=n, diagonals=diagonals, scheme="midpoint",
                                    first_increment=first).move(problem, u).displacement - u).max()

    err = [error(n, 0.3 / n) for n in (8, 16, 32)]
    rates = np.log2(np.array(err[:-1]) / err[1:])                # 2.06-2.12 (2.01-2.11 with equal ones)
    assert err[0] > 1e-8 and np.all(np.abs(rates - 2.0) < 0.15), (err, rates)
    assert error(3, 0.1) < 0.85 * error(3, 0.0)


@pytest.mark.parametrize("chi", [0.0, 1.0, 1.7])
def test_elastic_kernel_matches_the_slow_oracle(chi):
    rng = np.random.default_rng(9)
    Xe = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) + 0.2 * rng.uniform(-1, 1, (5, 4, 2))
    Ke = element_stiffness(Xe, *lame(2.5, 0.27), chi=chi)
    for e in range(5):
        np.testing.assert_allclose(Ke[e], elastic_quad(Xe[e], 2.5, 0.27, chi), rtol=1e-12, atol=1e-12)


def test_jacobian_stiffening_makes_small_elements_relatively_stiffer():
    Xe = np.array([[[0, 0], [1, 0], [1, 1], [0, 1]], [[0, 0], [0.1, 0], [0.1, 0.1], [0, 0.1]]], float)
    lam, mu = lame(1.0, 0.3)
    for chi, ratio in ((0.0, 1.0), (1.0, 100.0), (2.0, 1e4)):        # K ~ h^0 J^(-chi), J ~ h^2
        K = element_stiffness(Xe, lam, mu, chi=chi)
        assert K[1, 0, 0] / K[0, 0, 0] == pytest.approx(ratio, rel=1e-12)


def test_jacobian_stiffening_does_nothing_on_a_uniform_mesh_in_one_increment_and_acts_in_increments():
    """On a uniform mesh every element has the same ``J``, so ``J^(-chi)`` is one factor for all
    and, with prescribed motion only, the solution of one increment is the same for every chi
    (to the solve's round-off); in increments on the updated mesh the current ``J_e`` differ and
    chi changes the mesh (the large scene's uniform mesh: docs/optimization.md section 4)."""
    s = np.linspace(0.0, 1.0, 11)
    mesh = StructuredQuadMesh(s, s)
    boundary = np.unique(np.concatenate([mesh.side_nodes(side) for side in ("left", "right", "bottom", "top")]))
    inner = np.flatnonzero((np.abs(mesh.centroids - 0.5) < 0.15).all(axis=1))
    fixed = np.union1d(boundary, np.unique(mesh.quads[inner]))
    problem = MotionProblem.from_mesh(mesh, np.setdiff1d(np.arange(mesh.n_elements), inner), fixed)
    u = np.zeros((mesh.n_nodes, 2))
    core = np.unique(mesh.quads[inner])
    u[core] = rotation(mesh.points[core], 25.0) + [0.08, 0.0]
    move = lambda chi, n: movers.create("linear", chi=chi, increments=n).move(problem, u).displacement
    one = [move(chi, 1) for chi in (0.0, 1.0, 2.0)]
    assert np.abs(one[1] - one[0]).max() <= 1e-12 and np.abs(one[2] - one[0]).max() <= 1e-12
    assert np.abs(move(1.0, 8) - move(0.0, 8)).max() > 1e-3 * np.abs(u).max()


@pytest.mark.parametrize("mode", ["translation", "rotation", "bending"])
def test_yeoh_keeps_every_foil_mesh_valid(mode):
    scene = load("foil_in_channel", f"deformation.mode={mode}", "mover.name=yeoh")
    setup, result = run_move(scene)
    assert result.report.converged and result.report.quality[-1]["n_inverted"] == 0
    moved = setup.mesh.points + result.displacement
    assert not quality.inverted(moved, setup.mesh.quads).any()
    # the structure moved exactly as prescribed
    fixed = setup.problem.fixed_nodes
    np.testing.assert_allclose(result.displacement[fixed], setup.prescribed[fixed], atol=1e-14)


def _min_skew(scene):
    try:
        return run_move(scene)[1].report.quality[-1]["min_skewness"]
    except NumericalError as err:
        return err.diagnostic["quality"]["min_skewness"]


TWO_LAYERS = {"spring": "[2.15, 1.25]", "linear": "[8.0, 4.0]", "yeoh": "[2.2, 1.45]"}


@pytest.mark.parametrize("mode", ["translation", "rotation", "bending"])
@pytest.mark.parametrize("name", MOVERS)
def test_two_layer_stiffening_raises_min_skewness(name, mode):
    base = ("foil_in_channel", f"deformation.mode={mode}", f"mover.name={name}")
    plain = _min_skew(load(*base))
    stiff = _min_skew(load(*base, f"mover.layers={TWO_LAYERS[name]}"))
    assert stiff > plain + 0.02, (plain, stiff)


def test_stiffening_factors_reach_the_layers():
    scene = load("foil_in_channel", "mover.layers=[3.0, 2.0]")
    setup = motion_setup(scene)
    moving_layer = setup.layer[setup.moving]
    np.testing.assert_array_equal(setup.problem.stiffening[moving_layer == 1], 3.0)
    np.testing.assert_array_equal(setup.problem.stiffening[moving_layer == 2], 2.0)
    np.testing.assert_array_equal(setup.problem.stiffening[moving_layer > 2], 1.0)


def test_registry_lists_and_validates():
    names = movers.available()
    assert names == sorted(names) and set(MOVERS) <= set(names)
    for name in names:                                 # each entry creates the mover it names
        assert movers.create(name).name == name
    with pytest.raises(InputError) as err:
        movers.create("yeoh", A10=-1.0)
    assert err.value.key == "mover.yeoh.A10"
    with pytest.raises(InputError):
        movers.create("nonesuch")


def test_third_party_mover_is_found_through_its_entry_point(tmp_path):
    (tmp_path / "fake_mover.py").write_text(textwrap.dedent("""
        from dataclasses import dataclass
        from movers.linear import LinearElasticMover, LinearParams
        class FakeMover(LinearElasticMover):
            name = "fake"
    """))
    dist = tmp_path / "fake_mover-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-mover\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[tofsi.movers]\nfake = fake_mover:FakeMover\n")
    code = ("import movers, tofsi, json; "
            f"s = tofsi.load_scene({str(scene_path('foil_in_channel'))!r}, ['mover.name=fake']); "
            "print(json.dumps([movers.available(), s.mover.name]))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(tmp_path), "PATH": ""})
    assert run.returncode == 0, run.stderr
    names, chosen = json.loads(run.stdout)
    assert chosen == "fake" and "fake" in names and set(MOVERS) <= set(names) and names == sorted(names)


CONTRACT = {"min_skewness", "min_area_change", "max_area_change", "n_inverted", "converged", "wall_time_s"}


@pytest.mark.parametrize("scene", ["beam_in_channel", "foil_in_channel"])
@pytest.mark.parametrize("name", ["spring", "yeoh"])
def test_tofsi_move_json_has_the_contract_keys(scene, name, cli, tmp_path):
    run = cli("move", scene_path(scene), "--set", f"mover.name={name}", "--output", tmp_path, "--json")
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    assert CONTRACT <= set(figures) and figures["converged"] and figures["n_inverted"] == 0
    assert -1.0 <= figures["min_skewness"] <= 1.0
    assert {"moved_mesh.vtu", "moved_mesh.png", "move.json"} <= {p.name for p in tmp_path.iterdir()}


def test_tofsi_move_reports_an_inverted_linear_mesh_with_status_3(cli, tmp_path):
    run = cli("move", scene_path("foil_in_channel"), "--set", "mover.name=linear", "--output", tmp_path, "--json")
    assert run.returncode == 3
    diagnostic = json.loads((tmp_path / "diagnostic.json").read_text())
    assert diagnostic["quality"]["n_inverted"] > 0 and "worst_element" in diagnostic["quality"]
    assert json.loads(run.stdout)["converged"] is False


@pytest.mark.parametrize("name", MOVERS)
def test_foil_squeezed_against_the_wall_ends_in_status_3(name, cli, tmp_path):
    """The foil's lower face moves from y = 0.475 to 0.001, still inside the channel: the fluid
    layer below it is crushed 475-fold, which every mover fails at. (Through the wall, e.g. by
    0.6 m, is bad input: exit 2 before moving, see test_failures.py.)"""
    run = cli("move", scene_path("foil_in_channel"), "--set", f"mover.name={name}",
              "--set", "deformation.translation=0.474", "--set", "mover.yeoh.max_cutbacks=6", "--output", tmp_path)
    assert run.returncode == 3, run.stderr
    assert "Traceback" not in run.stderr and (tmp_path / "diagnostic.json").is_file()


def test_a_hopeless_yeoh_move_fails_once_one_element_blocks_its_cut_steps():
    """The foil squeezed against the wall (above): each cut step creeps nearer the fold of the
    same element, down to ``min_increment`` after 17 cutbacks; the move fails once that element
    has blocked ``BLOCKED_CUTBACKS`` of them, naming it (no successful move in the tests has one
    element block more than 2)."""
    with pytest.raises(NumericalError, match=r"inverts element 1032 at .*; that element blocked 8 of \d+ cut steps") as err:
        run_move(load("foil_in_channel", "mover.name=yeoh", "deformation.translation=0.474"))
    assert err.value.diagnostic["report"]["cutbacks"] < 17


@pytest.mark.parametrize("name", MOVERS)
def test_the_amg_path_gives_the_direct_answer(name):
    scene = load("foil_in_channel", f"mover.name={name}", "deformation.mode=rotation",
                 "deformation.rotation_deg=10", f"mover.{name}.linear_tol=1e-12")
    direct = run_move(scene)[1].displacement
    result = run_move(load("foil_in_channel", f"mover.name={name}", "deformation.mode=rotation",
                           "deformation.rotation_deg=10", f"mover.{name}.linear_tol=1e-12",
                           f"mover.{name}.tangent_solver=amg"))[1]
    np.testing.assert_allclose(result.displacement, direct, atol=1e-8 * np.abs(direct).max())
    report = result.report
    if report.linear_solves > 1:        # increments and Newton steps recycle AMG hierarchies
        assert report.factorizations <= report.linear_solves / 2, report


def test_a_move_in_increments_whose_element_matrices_break_fails_with_a_diagnosis():
    """Linear elasticity with ``chi = 1/2`` weights each quad by ``det J^(1/2)``: bent 2 m in 3
    increments, the first inverts quads, so the second's element matrices are NaN there. The
    move fails as a NumericalError naming those quads and the worst element the first increment
    left (it ended in a bare ValueError from GMRES before)."""
    import tofsi
    from tofsi.core.errors import NumericalError
    scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization_fsi.toml",
                             ["mesh.h_min=0.1", "mesh.h_max=0.1", "mover.name=linear",
                              "mover.linear.increments=3", "mover.linear.chi=0.5"])
    model = tofsi.Problem(scene).model
    mesh = model.mesh
    c = mesh.centroids
    rho = np.where((np.abs(c[:, 0] - 1.0) < 0.15) & (c[:, 1] < 0.6), 0.9, 0.1)
    X, Y = mesh.points[:, 0], mesh.points[:, 1]
    bend = np.column_stack([(Y / 0.6) ** 2 * np.exp(-((X - 1.0) / 0.3) ** 2), 0.0 * X]).ravel()
    with np.errstate(invalid="ignore"), pytest.raises(NumericalError) as failure:
        model.motion.move(2.0 * bend, rho)
    message = str(failure.value)
    assert "linear mover: the element matrices of" in message and "at increment 2" in message
    assert "after increment 1 the worst element is" in message
    assert "(elements 117, 118" in message          # by the mesh's numbering, where the first inverted
