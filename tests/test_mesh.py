"""Structured meshes: orientation, conformity, interface, layers, Q2 numbering."""

import numpy as np
import pytest

from tofsi.mesh import quality
from tofsi.mesh.channel import build_mesh, inside
from tofsi.mesh.grading import graded_axis
from tofsi.mesh.layers import element_layers, stiffening_field
from tofsi.mesh.structured import DESIGN, FLUID, SOLID, StructuredQuadMesh

from conftest import load


def test_every_element_is_counter_clockwise_with_positive_area(shipped_mesh):
    _, mesh = shipped_mesh
    assert np.all(quality.signed_area(mesh.points, mesh.quads) > 0)
    assert np.all(quality.skewness(mesh.points, mesh.quads) == pytest.approx(1.0))
    # bottom-left corner first
    P = mesh.points[mesh.quads]
    assert np.all(P[:, 0, 0] < P[:, 1, 0]) and np.all(P[:, 0, 1] < P[:, 3, 1])


def test_grid_lines_hit_every_rectangle_corner(shipped_mesh):
    scene, mesh = shipped_mesh
    g = scene.geometry
    rects = list(g.solids) + list(g.holes) + ([g.design] if g.design else [])
    for x0, x1, y0, y1 in rects:
        for x in (x0, x1):
            assert np.min(np.abs(mesh.xs - x)) < 1e-12
        for y in (y0, y1):
            assert np.min(np.abs(mesh.ys - y)) < 1e-12


def test_regions_follow_the_rectangles(shipped_mesh):
    scene, mesh = shipped_mesh
    g = scene.geometry
    c = mesh.centroids
    solid = np.zeros(len(c), bool)
    for r in g.solids:
        solid |= inside(c, r)
    for r in g.holes:
        solid &= ~inside(c, r)
    np.testing.assert_array_equal(mesh.region == SOLID, solid)
    if g.design:
        np.testing.assert_array_equal(mesh.region == DESIGN, inside(c, g.design) & ~solid)


def _geometric_solid(point, scene):
    g = scene.geometry
    return any(inside(point[None], r)[0] for r in g.solids) and \
        not any(inside(point[None], r)[0] for r in g.holes)


@pytest.mark.parametrize("name", ["beam_in_channel", "foil_in_channel"])
def test_interface_is_exactly_the_boundary_between_solid_and_fluid(name):
    scene = load(name)
    mesh = build_mesh(scene.geometry, scene.mesh)
    expected = []
    dx, dy = np.diff(mesh.xs).min() / 4, np.diff(mesh.ys).min() / 4
    for k, (x, y) in enumerate(mesh.points):            # test oracle: a loop over nodes
        probes = [np.array([x + sx * dx, y + sy * dy]) for sx in (-1, 1) for sy in (-1, 1)]
        probes = [p for p in probes if 0 < p[0] < scene.geometry.length and 0 < p[1] < scene.geometry.height]
        kinds = {_geometric_solid(p, scene) for p in probes}
        if kinds == {True, False}:
            expected.append(k)
    np.testing.assert_array_equal(mesh.interface_nodes, expected)
    assert mesh.interface_edges.shape[1] == 2
    assert set(mesh.interface_edges.ravel()) <= set(expected)


def test_layers_grow_one_node_ring_at_a_time():
    """Every layer k = 1..4 against a slow breadth-first search over the elements: layer 1 is
    the fluid quads touching an interface node, layer k + 1 the fluid quads not yet counted that
    share a node with layer k; quads beyond the counted layers, and the solid, are 0."""
    scene = load("beam_in_channel")
    mesh = build_mesh(scene.geometry, scene.mesh)
    n_layers = 4
    layer = element_layers(mesh.incidence, mesh.interface_nodes, mesh.region != SOLID, n_layers=n_layers)
    fluid = [e for e in range(mesh.n_elements) if mesh.region[e] != SOLID]
    expected = np.zeros(mesh.n_elements, dtype=int)
    front = set(mesh.interface_nodes.tolist())
    for k in range(1, n_layers + 1):
        ring = [e for e in fluid if expected[e] == 0 and front & set(mesh.quads[e].tolist())]
        expected[ring] = k
        front = {int(i) for e in ring for i in mesh.quads[e]}
    assert all((expected == k).any() for k in range(1, n_layers + 1))
    np.testing.assert_array_equal(layer, expected)


def test_stiffening_field_maps_layers_to_factors():
    layer = np.array([0, 1, 2, 3, 1, 0])
    np.testing.assert_array_equal(stiffening_field(layer, [2.0, 1.5]), [1, 2, 1.5, 1, 2, 1])


def test_q2_nodes_are_corners_midsides_and_centres_of_the_same_quads():
    mesh = StructuredQuadMesh(np.array([0, 0.3, 1.0, 1.2]), np.array([0, 0.5, 0.6]))
    P9 = mesh.points9()
    q9 = mesh.quads9
    assert len(np.unique(q9)) == mesh.n_nodes9 == 7 * 5
    np.testing.assert_array_equal(q9[:, :4], mesh.quads)
    C = P9[q9[:, :4]]
    for k, (a, b) in enumerate([(0, 1), (1, 2), (2, 3), (3, 0)]):
        np.testing.assert_allclose(P9[q9[:, 4 + k]], 0.5 * (C[:, a] + C[:, b]))
    np.testing.assert_allclose(P9[q9[:, 8]], C.mean(axis=1))
    # neighbours share the Q2 nodes of their common edge
    right_of_0 = 1
    assert q9[0, 5] == q9[right_of_0, 7]
    np.testing.assert_allclose(P9[mesh.side_nodes9("left")][:, 0], 0.0)
    assert len(mesh.side_nodes9("top")) == 2 * mesh.nx + 1


def test_q2_nodes_follow_the_bilinear_map_of_a_deformed_mesh():
    mesh = StructuredQuadMesh(np.linspace(0, 1, 4), np.linspace(0, 1, 3))
    rng = np.random.default_rng(1)
    moved = mesh.points + 0.05 * rng.normal(size=mesh.points.shape)
    from tofsi.fem.geometry import map_points
    from tofsi.fem.shapes import Q2_NODES
    expected = map_points(moved[mesh.quads], Q2_NODES)      # (E, 9, 2)
    np.testing.assert_allclose(mesh.points9(moved)[mesh.quads9], expected, atol=1e-15)


def test_graded_axis_is_fine_at_features_and_contains_breakpoints():
    xs = graded_axis(2.0, [0.95, 1.05, 0.975], [(0.95, 1.05)], 0.01, 0.1, 1.2)
    h = np.diff(xs)
    assert xs[0] == 0.0 and xs[-1] == 2.0
    for b in (0.95, 0.975, 1.05):
        assert np.min(np.abs(xs - b)) < 1e-15
    inside_feature = (xs[:-1] >= 0.95 - 1e-12) & (xs[1:] <= 1.05 + 1e-12)
    assert np.allclose(h[inside_feature], 0.01, rtol=0.3)
    assert h.max() <= 0.1 * 1.15
    assert np.max(h[1:] / h[:-1]) < 1.2 * 1.15 and np.min(h[1:] / h[:-1]) > 1 / (1.2 * 1.15)


def test_node_sets_lie_on_their_sides(shipped_mesh):
    scene, mesh = shipped_mesh
    P = mesh.points
    sets = mesh.node_sets
    assert np.all(P[sets["inlet"], 0] == 0) and np.all(P[sets["outlet"], 0] == scene.geometry.length)
    assert np.all(P[sets["bottom"], 1] == 0) and np.all(P[sets["top"], 1] == scene.geometry.height)
    assert len(sets["inlet"]) == mesh.ny + 1


def test_region_defaults_to_fluid():
    mesh = StructuredQuadMesh([0, 1, 2], [0, 1])
    assert np.all(mesh.region == FLUID) and mesh.interface_nodes.size == 0
