"""Band-localized mesh motion: what moves, what stays, how close to the full domain, derivatives."""

import numpy as np
import pytest

import tofsi
from adjoint.checks import central_difference, relative_error
from tofsi.core.errors import InputError
from tofsi.mesh.structured import SOLID
from tofsi.coupling.motion import moved_quality, motion_setup, run_move

from conftest import load
from gradient_checks import check_total_derivative

MOVERS = ["linear", "spring", "yeoh"]
SMALL = ["mesh.h_min=0.025", "mesh.h_max=0.05", "deformation.mode=rotation", "deformation.rotation_deg=8"]


def foil(*overrides):
    return load("foil_in_channel", *SMALL, *overrides)


def test_band_by_layers_moves_only_its_quads_and_holds_its_edge():
    setup, result = run_move(foil("mover.name=linear", "mover.band.mode=layers", "mover.band.layers=4"))
    motion, mesh = setup.motion, setup.mesh
    band = motion.band
    assert band is not None and 0 < setup.moving.size < motion.movable.size
    assert np.all(setup.layer[setup.moving] >= 1) and np.all(setup.layer[setup.moving] <= 4)
    layered = np.flatnonzero((setup.layer >= 1) & (setup.layer <= 4))
    assert set(layered) == set(setup.moving)                         # exactly the first four layers
    x = result.displacement
    inside = np.unique(mesh.quads[setup.moving])
    outside = np.setdiff1d(np.arange(mesh.n_nodes), np.union1d(inside, mesh.nodes_of(SOLID)))
    assert np.all(x[band.edge_nodes] == 0.0) and np.all(x[outside] == 0.0)
    free = np.setdiff1d(inside, np.union1d(band.edge_nodes, mesh.nodes_of(SOLID)))
    assert np.abs(x[free]).max() > 1e-3                              # the band itself moves
    np.testing.assert_array_equal(x[mesh.nodes_of(SOLID)], setup.prescribed[mesh.nodes_of(SOLID)])


def test_band_by_distance_reaches_that_far_and_auto_scales_with_the_motion():
    setup = motion_setup(foil("mover.name=linear", "mover.band.mode=distance", "mover.band.distance=0.1"))
    mesh = setup.mesh
    solid_nodes = mesh.points[mesh.nodes_of(SOLID)]
    corners = mesh.points[mesh.quads[setup.moving]]                  # (Em, 4, 2)
    nearest = np.min(np.linalg.norm(corners[:, :, None, :] - solid_nodes[None, None], axis=-1), axis=2)
    assert np.all(nearest.min(axis=1) <= 0.1 + 1e-12)                # every band quad is within reach
    out = np.setdiff1d(setup.motion.movable, setup.moving)
    far = np.min(np.linalg.norm(mesh.points[mesh.quads[out]][:, :, None, :] - solid_nodes[None, None],
                                axis=-1), axis=2)
    assert np.all(far.min(axis=1) > 0.1)                             # and every other is not
    auto = ["mover.name=linear", "mover.band.mode=auto", "mover.band.motion_multiple=3", "mover.band.layers=1"]
    small = motion_setup(foil(*auto))
    big = motion_setup(foil(*auto, "deformation.rotation_deg=16"))
    size = np.linalg.norm(small.prescribed, axis=1).max()
    assert small.motion.band.reach == pytest.approx(3 * size)
    assert big.moving.size > small.moving.size


@pytest.mark.parametrize("name", MOVERS)
def test_a_band_covering_the_mesh_is_the_full_domain_solve(name):
    full = run_move(foil(f"mover.name={name}"))[1].displacement
    setup, result = run_move(foil(f"mover.name={name}", "mover.band.mode=distance", "mover.band.distance=5.0"))
    assert setup.moving.size == setup.motion.movable.size
    np.testing.assert_allclose(result.displacement, full, atol=1e-10 * np.abs(full).max())


@pytest.mark.parametrize("name", MOVERS)
def test_automatic_band_is_within_001_min_skewness_of_the_full_domain(name):
    """The 8 degree rotation of the benchmark: the automatic band (default multiple) keeps the
    minimum skewness within 0.01 of the full-domain solve while moving fewer quads."""
    scene_full = foil(f"mover.name={name}")
    setup_full, full = run_move(scene_full)
    setup, band = run_move(foil(f"mover.name={name}", "mover.band.mode=auto"))
    q_full, q_band = moved_quality(setup_full, full.displacement), moved_quality(setup, band.displacement)
    assert q_full.n_inverted == 0
    assert setup.moving.size < setup_full.moving.size
    assert abs(q_band.min_skewness - q_full.min_skewness) < 0.01, (q_band.min_skewness, q_full.min_skewness)


@pytest.mark.parametrize("name,params", [("linear", []), ("yeoh", ["mover.yeoh.newton_tol=1e-13"]),
                                         ("spring", ["mover.spring.increments=3",
                                                     "mover.spring.diagonals=both"])])
def test_band_motion_vjp_matches_central_differences(name, params):
    setup = motion_setup(foil(f"mover.name={name}", f"mover.{name}.linear_tol=1e-15", *params,
                              "mover.band.mode=layers", "mover.band.layers=3"))
    motion, u = setup.motion, setup.prescribed
    result = motion.move(u)
    rng = np.random.default_rng(3)
    x_bar = rng.normal(size=u.shape)
    u_bar, _ = motion.vjp(result, x_bar)
    du = np.zeros_like(u)
    du[motion.follows] = rng.normal(size=(motion.follows.size, 2))
    f = lambda t: float(np.sum(x_bar * motion.move(u + t * du).displacement))
    assert relative_error(central_difference(f, 0.0, 1.0, 1e-6), u_bar @ du.ravel()) < 1e-6


def test_bad_band_settings_are_input_errors():
    with pytest.raises(InputError, match="mover.band.mode"):
        foil("mover.band.mode=wide")
    with pytest.raises(InputError, match="mover.band.layers"):
        foil("mover.band.layers=0")
    with pytest.raises(InputError, match="mover.band.frobnicate"):
        foil("mover.band.frobnicate=1")


# ---- inside a two-way optimization: the total derivative with the band on ------------------
BASE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13",
        "design.filter_radius=0.15", "structure.youngs_modulus=2e4", "coupled.tol=1e-12",
        "mover.yeoh.newton_tol=1e-13", "mover.linear.linear_tol=1e-14", "mover.spring.linear_tol=1e-14",
        "effects.coupling=two-way", "structure.load_exponent=3", "geometry.design=[0.6, 1.4, 0.0, 0.6]",
        "mover.band.mode=layers", "mover.band.layers=2"]
TWO_WAY = {"yeoh": ["mover.name=yeoh"], "linear": ["mover.name=linear"],
           "spring-3": ["mover.name=spring", "mover.spring.increments=3", "mover.spring.diagonals=both"]}


@pytest.mark.parametrize("objective", ["compliance", pytest.param("pressure-drop", marks=pytest.mark.slow)])
@pytest.mark.parametrize("mover", list(TWO_WAY))
def test_two_way_total_derivative_with_the_band(mover, objective):
    P = tofsi.Problem(load("beam_in_channel_optimization", *BASE, *TWO_WAY[mover],
                           f"design.objective={objective}"))
    motion, mesh = P.model.motion, P.model.mesh
    assert motion.band is not None and motion.moving.size < mesh.n_elements
    assert np.setdiff1d(motion.band.edge_nodes, mesh.boundary_nodes).size > 0   # an interior edge
    rng = np.random.default_rng(1)
    gamma, d = rng.uniform(0.05, 0.95, P.n_design), rng.normal(size=P.n_design)
    t, cd_error, _ = check_total_derivative(P, gamma, d)
    assert t.min_rate > 1.9 and cd_error < 1e-5, (t, cd_error)
    x = P.solve(gamma).mesh_displacement
    assert np.all(x[motion.band.outside_nodes] == 0.0) and np.abs(x).max() > 0
