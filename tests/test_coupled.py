"""Coupled solves, the mesh-motion block's derivatives, and effects that cost nothing when off."""

import json

import numpy as np
import pytest

from tofsi.coupling.coupled import CoupledModel
from tofsi.core.errors import InputError
from tofsi.physics.mesh_motion import MeshMotion, solid_indicator

from conftest import load, scene_path

SOFT = ["mesh.h_min=0.05", "mesh.h_max=0.05", "effects.coupling=two-way", "mover.name=yeoh",
        "structure.youngs_modulus=5e5", "fluid.alpha_max=1e4", "coupled.tol=1e-10"]


def soft_model(method, *extra):
    scene = load("beam_in_channel_optimization", *SOFT, f"coupled.method={method}", *extra)
    model = CoupledModel(scene)
    design = model.design_elements
    c = model.mesh.centroids[design]
    rho = model.densities(((np.abs(c[:, 0] - 1.0) < 0.1) & (c[:, 1] < 0.6)).astype(float))
    return model, rho


def test_partitioned_and_monolithic_agree_and_newton_is_quadratic():
    part, rho = soft_model("partitioned")
    mono, _ = soft_model("monolithic", "coupled.quasi_newton=false")
    quasi, _ = soft_model("monolithic")
    a, b, c = part.solve(rho), mono.solve(rho), quasi.solve(rho)
    assert np.abs(a.x).max() > 1e-3                        # the mesh visibly moves
    for f in ("u", "x", "w"):
        ref = getattr(a, f)
        assert np.abs(getattr(b, f) - ref).max() <= 1e-8 * np.abs(ref).max()
        assert np.abs(getattr(c, f) - ref).max() <= 1e-8 * np.abs(ref).max()
    r = [max(h["u"], h["x"], h["w"]) for h in b.reports["coupling"]["history"]]
    # quadratic: r_{k+1} <= C r_k^2 (C = 10, the residuals are scaled to order 1) above round-off
    steps = [(r[k], r[k + 1]) for k in range(len(r) - 1) if r[k] < 1e-2]
    assert steps and all(after <= 10 * before**2 + 1e-13 for before, after in steps), r
    assert r[-1] <= 1e-10
    # quasi-Newton (shape derivatives of the first iterate): still converges, at least linearly fast
    q = [max(h["u"], h["x"], h["w"]) for h in c.reports["coupling"]["history"]]
    assert q[-1] <= 1e-10 and len(q) <= len(r) + 3, (q, r)


def test_a_move_in_increments_is_solved_monolithic_but_not_by_one_lu_of_the_whole_jacobian():
    """The spring in increments (a path-dependent move) is the residual ``x - M(u)``: ``auto``
    chooses the monolithic Newton for it; its coupling is known by its products only, so a
    whole-Jacobian LU (``coupled.jacobian_solver = "direct"``) is refused before any solve."""
    model, _ = soft_model("auto", "mover.name=spring", "mover.spring.increments=4")
    assert model.motion.path_dependent
    assert model.system.method_for(model.system.cycles[0]) == "monolithic"
    with pytest.raises(InputError) as err:
        soft_model("monolithic", "mover.name=spring", "coupled.jacobian_solver=direct")
    assert err.value.key == "coupled.jacobian_solver"


RESIDUAL_MOVERS = [("yeoh", []), ("linear", []), ("spring", ["mover.spring.diagonals=both",
                                                             "mover.spring.increments=1"])]


@pytest.mark.parametrize("design", [False, True], ids=["explicit", "blended"])
@pytest.mark.parametrize("name,extra", RESIDUAL_MOVERS, ids=[m for m, _ in RESIDUAL_MOVERS])
def test_mesh_motion_blocks_match_central_differences(name, extra, design):
    scene_name = "beam_in_channel_optimization" if design else "beam_in_channel"
    scene = load(scene_name, "mesh.h_min=0.1", "mesh.h_max=0.2", f"mover.name={name}", *extra,
                 "mover.layers=[1.7]")
    from tofsi.mesh.channel import build_mesh
    mesh = build_mesh(scene.geometry, scene.mesh)
    motion = MeshMotion(mesh, scene)
    rng = np.random.default_rng(41)
    rho = rng.uniform(0.05, 0.95, mesh.n_elements)
    u = 0.002 * rng.normal(size=2 * mesh.n_nodes)
    x = 0.002 * rng.normal(size=2 * mesh.n_nodes)      # small: the notch's legs are 0.025 wide
    D = lambda x_=x, u_=u, r_=rho: motion.residual(x_, u_, r_)[0]
    _, Dx = motion.residual(x, u, rho)
    Du = motion.structure_partial(rho)
    h = 1e-6
    for _ in range(2):
        d = rng.normal(size=x.size)
        fd = (D(x_=x + h * d) - D(x_=x - h * d)) / (2 * h)
        assert np.linalg.norm(Dx @ d - fd) <= 1e-6 * np.linalg.norm(fd)
        fd = (D(u_=u + h * d) - D(u_=u - h * d)) / (2 * h)
        assert np.linalg.norm(Du @ d - fd) <= 1e-6 * max(np.linalg.norm(fd), 1e-12)
        if design:
            lam = rng.normal(size=x.size)
            dr = rng.normal(size=rho.size)
            fd = lam @ (D(r_=rho + h * dr) - D(r_=rho - h * dr)) / (2 * h)
            _, rho_bar = motion.partials_transpose(x, u, rho, lam)
            assert rho_bar @ dr == pytest.approx(fd, rel=1e-6)


def test_solid_indicator_is_exactly_one_from_the_threshold_on_and_smooth():
    """Hand values of ``h(rho) = 10 t^3 - 15 t^4 + 6 t^5``, ``t = rho / r``: ``h(0.3) = 0.216 * 3.16``
    at threshold 1/2, ``h(0.2) = 0.008 * 7.24`` and ``h(0.3) = 0.027 * 6.04`` at threshold 1; a node
    of an element at or above the threshold has ``s = 1`` exactly; the derivative against central
    differences (also straddling the threshold and zero), and ``h`` twice differentiable at the
    threshold (the first-order model's remainder falls as eps^3 there)."""
    quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4]])
    s, _ = solid_indicator(np.array([0.5, 0.3]), quads, 6)
    assert s[[0, 1, 3, 4]].tolist() == [1.0] * 4                   # exactly, not nearly
    np.testing.assert_allclose(s[[2, 5]], 0.216 * 3.16, rtol=1e-14)
    s, _ = solid_indicator(np.array([0.2, 0.3]), quads, 6, threshold=1.0)
    a, b = 0.008 * 7.24, 0.027 * 6.04
    np.testing.assert_allclose(s, [a, 1 - (1 - a) * (1 - b), b] * 2, rtol=1e-13)
    rng = np.random.default_rng(2)
    h = 1e-7
    for rho in (rng.uniform(0, 1, 2), np.array([0.45, 0.55]), np.array([0.0, 0.02])):
        d = rng.normal(size=2)
        fd = (solid_indicator(rho + h * d, quads, 6)[0] - solid_indicator(rho - h * d, quads, 6)[0]) / (2 * h)
        np.testing.assert_allclose(solid_indicator(rho, quads, 6)[1] @ d, fd, rtol=1e-7, atol=1e-12)
    rho, d = np.array([0.5, 0.3]), np.array([1.0, 0.0])             # at the threshold itself
    s0, ds = solid_indicator(rho, quads, 6)
    rem = [np.abs(solid_indicator(rho - e * d, quads, 6)[0] - s0 + e * (ds @ d)).max() for e in (1e-2, 5e-3)]
    assert np.log2(rem[0] / rem[1]) > 2.9


def test_a_mesh_motion_study_never_assembles_a_fluid_matrix_even_when_the_scene_has_a_flow(monkeypatch):
    """``move`` of a scene with a fluid effect moves the mesh without a flow solve; the spy has
    teeth: the ``fsi`` motion of the same kind of study does solve the flow through it."""
    import tofsi.physics.fluid_kernel as kernel
    from tofsi.coupling.motion import run_move
    calls, element = [], kernel.fluid_elements
    monkeypatch.setattr(kernel, "fluid_elements", lambda *a, **k: calls.append(1) or element(*a, **k))
    scene = load("foil_in_channel", "effects.fluid=navier-stokes", "effects.structure=linear-elastic",
                 "mesh.h_min=0.05", "mesh.h_max=0.1")
    assert scene.effects.fluid == "navier-stokes"
    run_move(scene)
    assert calls == []
    run_move(load("beam_in_channel", "deformation.mode=fsi", "mesh.h_min=0.05", "mesh.h_max=0.1"))
    assert len(calls) > 0
    with pytest.raises(InputError):
        CoupledModel(load("foil_in_channel")).solve(None)


def test_a_one_way_scene_never_calls_the_mover(monkeypatch):
    import movers.yeoh
    monkeypatch.setattr(movers.yeoh.YeohMover, "move", lambda *a, **k: pytest.fail("mover called"))
    scene = load("beam_in_channel_optimization", "mesh.h_min=0.1", "mesh.h_max=0.1", "mover.name=yeoh")
    model = CoupledModel(scene)
    assert model.motion is None
    state = model.solve(model.densities())
    assert state.x is None and state.u is not None


def test_stokes_effect_drops_inertia_and_structure_off_drops_the_structure():
    scene = load("beam_in_channel_optimization", "mesh.h_min=0.1", "mesh.h_max=0.1",
                 "effects.fluid=stokes", "effects.structure=none", "design.objective=dissipation")
    model = CoupledModel(scene)
    assert model.structure is None and model.flow.density == 0.0
    state = model.solve(model.densities())
    assert state.u is None and state.reports["flow"]["newton_iterations"] == 1


def test_fsi_deformation_bends_the_beam_downstream_to_the_requested_tip():
    scene = load("beam_in_channel", "deformation.mode=fsi", "mesh.h_min=0.025", "mesh.h_max=0.1")
    from tofsi.coupling.motion import motion_setup
    setup = motion_setup(scene)
    u = setup.prescribed
    assert np.max(np.linalg.norm(u, axis=1)) == pytest.approx(0.15, rel=1e-12)
    tip = np.argmax(np.linalg.norm(u, axis=1))
    assert u[tip, 0] > 0 and setup.mesh.points[tip, 1] == pytest.approx(0.5)


def test_tofsi_solve_writes_fields_and_figures(cli, tmp_path):
    run = cli("solve", scene_path("beam_in_channel_optimization"), "--set", "mesh.h_min=0.1",
              "--set", "mesh.h_max=0.1", "--output", tmp_path, "--json")
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    assert figures["converged"] and figures["pressure_drop"] > 0 and figures["compliance"] > 0
    names = {p.name for p in tmp_path.iterdir()}
    assert {"solution.vtu", "solution_velocity.png", "solution_pressure.png", "solve.json"} <= names
    import meshio
    m = meshio.read(tmp_path / "solution.vtu")
    assert {"velocity", "pressure", "structure_displacement"} <= set(m.point_data)


def test_a_single_fields_ordering_is_its_physics_own_and_the_grids_nested_dissection():
    """The block preconditioner's per-field orderings are the permutations the fields' own solves
    factorize with (one object, made once), and equal the nested dissection of the block's grid
    made anew (truth: :func:`tofsi.linalg.nested_dissection`); several fields get their own."""
    from tofsi.linalg import nested_dissection
    model, _ = soft_model("monolithic")
    system = model.system
    own = {"w": model.flow.ordering, "u": model.structure.perm, "x": model.motion.base.ordering}
    for name in system.names:
        perm = system.ordering((name,))
        assert perm is own[name]
        coords, last = system.by_name[name].ordering_grid()
        np.testing.assert_array_equal(perm, nested_dissection(coords, last=last))
    both = system.ordering(("w", "u"))
    assert both.size == system.by_name["w"].size + system.by_name["u"].size
    assert np.array_equal(np.sort(both), np.arange(both.size))
