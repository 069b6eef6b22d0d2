"""The finite-strain structure's Newton solve (tofsi.physics.finite_strain) against hand values.

* a bar clamped on the left and pulled on the right by the traction of a homogeneous
  100 % stretch (nu = 0, so P22 = 0 and the clamp is compatible): the solve must return
  the homogeneous field, through load steps from zero;
* warm starts converge to the same displacement with fewer iterations;
* a load the void material cannot carry fails loudly with the worst element; without load
  steps (a coupled solve's direct attempt) a load Newton alone cannot reach fails after that
  Newton, where the load steps carry it;
* the energy interpolation carries the same load through linear void elements.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from tofsi.core.errors import NumericalError
from tofsi.fem.assembly import element_dofs
from tofsi.fem.dirichlet import DirichletOperator
from tofsi.fem.elasticity import lame
from tofsi.physics.interpolation import SIMP
from tofsi.linalg import DirectSolver, nested_dissection
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.physics.finite_strain import FiniteStrainElasticity


def settings(**kw):
    base = dict(poisson_ratio=0.0, interpolation="energy", energy_threshold=0.01, energy_sharpness=500.0,
                newton_tol=1e-10, max_newton=25, max_cutbacks=20)
    return SimpleNamespace(**{**base, **kw})


def structure(mesh, clamped_sides, **kw):
    dofs = element_dofs(mesh.quads, 2)
    clamped = np.unique(np.concatenate([mesh.side_nodes(s) for s in clamped_sides]))
    bc = DirichletOperator(dofs, dofs, 2 * mesh.n_nodes, element_dofs(clamped[:, None], 2).ravel())
    grid = np.repeat(mesh.grid_positions(), 2, axis=0)
    perm = nested_dissection(grid)
    return FiniteStrainElasticity(mesh, settings(**kw), bc, dofs, lambda A: DirectSolver(A, perm=perm))


def edge_traction(mesh, side, traction):
    """Consistent nodal forces of a uniform traction (per reference length) on a straight side."""
    nodes = mesh.side_nodes(side)
    coord = mesh.points[nodes, 1 if side in ("left", "right") else 0]
    order = np.argsort(coord)
    nodes, coord = nodes[order], coord[order]
    f = np.zeros((mesh.n_nodes, 2))
    for a, b, length in zip(nodes[:-1], nodes[1:], np.diff(coord), strict=True):
        f[[a, b]] += 0.5 * length * np.asarray(traction)
    return f.ravel()


def test_a_homogeneous_stretch_of_100_percent_through_load_steps():
    mesh = StructuredQuadMesh(np.linspace(0, 2.0, 9), np.linspace(0, 0.5, 3))
    st = structure(mesh, ["left"])
    E0, stretch = 2.0e3, 2.0
    _, mu = lame(E0, 0.0)
    P11 = mu * (stretch - 1.0 / stretch)
    rho = np.ones(mesh.n_elements)
    sol = st.solve(edge_traction(mesh, "right", [P11, 0.0]), rho, SIMP(E0, 1e-6 * E0, 3.0))
    exact = np.column_stack([(stretch - 1.0) * mesh.points[:, 0], np.zeros(mesh.n_nodes)]).ravel()
    np.testing.assert_allclose(sol.u, exact, atol=1e-9 * 2.0)
    assert sol.report.converged and sol.report.newton_iterations >= 3
    assert sol.report.min_det_F == pytest.approx(stretch, rel=1e-9)
    # the linear model would stretch by P11 / E = 0.75 instead of 1.0
    assert P11 / E0 == pytest.approx(0.75)


def beam_near_wall(**kw):
    """A beam 0.65 < x < 0.85, y < 0.8 standing on the clamped floor of a unit box of void (rho = 0)
    whose right side (a wall) is clamped too, pushed towards the wall at its top."""
    mesh = StructuredQuadMesh(np.linspace(0, 1.0, 21), np.linspace(0, 1.0, 21))
    st = structure(mesh, ["bottom", "right"], poisson_ratio=0.3, **kw)
    rho = np.where((np.abs(mesh.centroids[:, 0] - 0.75) < 0.1) & (mesh.centroids[:, 1] < 0.8), 1.0, 0.0)
    f = np.zeros((mesh.n_nodes, 2))
    f[mesh.node(np.arange(13, 18), 16), 0] = 0.2
    return mesh, st, rho, f.ravel()


def test_a_warm_start_converges_to_the_same_displacement_in_fewer_iterations():
    mesh, st, rho, f = beam_near_wall()
    simp = SIMP(1e3, 1e-3, 3.0)
    cold = st.solve(0.5 * f, rho, simp)
    assert np.abs(cold.u).max() > 0.1                         # large: 10 % of the box
    warm = st.solve(0.5 * f, rho, simp, guess=st.solve(0.45 * f, rho, simp).u)
    assert warm.report.warm_start and warm.report.newton_iterations < cold.report.newton_iterations
    np.testing.assert_allclose(warm.u, cold.u, atol=1e-8 * np.abs(cold.u).max())
    again = st.solve(0.5 * f, rho, simp, guess=cold.u, solver=cold.solver)
    assert again.report.newton_iterations == 0 and again.report.factorizations == 0


def test_plain_simp_crushes_the_void_and_fails_loudly_with_the_worst_element():
    """Plain SIMP at finite strain: the void between the beam and the wall (E = 1e-6 E0, but
    neo-Hookean) is squeezed towards det F = 0 and stalls Newton (it converges after 2 cutbacks
    and 136 Newton iterations); with one cutback allowed the solve fails, naming a void element
    and where it is."""
    mesh, st, rho, f = beam_near_wall(interpolation="simp", max_cutbacks=1)
    with pytest.raises(NumericalError) as err:
        st.solve(f, rho, SIMP(1e3, 1e-3, 3.0))
    d = err.value.diagnostic
    assert {"worst_element", "min_det_F", "centroid", "load_factor", "cutbacks"} <= set(d)
    assert d["load_factor"] < 1.0 and d["cutbacks"] == 2
    assert rho[d["worst_element"]] == 0.0 and 0.0 < d["min_det_F"] < 0.05
    assert d["centroid"][0] > 0.85                             # between the beam and the wall
    assert "smallest det F" in str(err.value)


def test_without_load_steps_a_load_newton_alone_cannot_reach_fails_after_that_newton():
    """Plain SIMP's beam near the wall: Newton from zero stalls; with load steps the solve
    converges (2 cutbacks, 136 Newton iterations), without them it fails after the one Newton,
    as soon as its residual has not halved in ``STALL_ITERATIONS`` (5) iterations (not after
    ``max_newton``, 25), naming the worst element."""
    from tofsi.physics.finite_strain import STALL_ITERATIONS
    mesh, st, rho, f = beam_near_wall(interpolation="simp")
    simp = SIMP(1e3, 1e-3, 3.0)
    with pytest.raises(NumericalError) as err:
        st.solve(f, rho, simp, load_steps=False)
    d = err.value.diagnostic
    assert "without load steps" in str(err.value) and f"did not halve in {STALL_ITERATIONS}" in str(err.value)
    assert d["newton_iterations"] == STALL_ITERATIONS and d["cutbacks"] == 0
    assert {"worst_element", "min_det_F", "centroid"} <= set(d)
    stepped = st.solve(f, rho, simp)
    assert stepped.report.converged and stepped.report.cutbacks > 0


def test_the_energy_interpolation_carries_the_load_without_cutbacks():
    mesh, st, rho, f = beam_near_wall(max_cutbacks=0)
    sol = st.solve(f, rho, SIMP(1e3, 1e-3, 3.0))
    assert sol.report.converged and sol.report.cutbacks == 0 and sol.report.newton_iterations <= 12
    assert np.abs(sol.u).max() > 0.2                          # a large motion of the beam
    assert sol.report.min_det_F > 0.9                         # the neo-Hookean (solid) part is mildly strained
