"""Skewness and area change against hand-computed values and invariance properties."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tofsi.mesh import quality

ONE = np.array([[0, 1, 2, 3]])


def skew(points):
    return quality.skewness(np.asarray(points, float), ONE)[0]


def test_unit_square_has_skewness_one():
    assert skew([[0, 0], [1, 0], [1, 1], [0, 1]]) == pytest.approx(1.0, abs=1e-15)


def test_sixty_degree_rhombus_has_skewness_two_thirds():
    h = math.sqrt(3) / 2
    assert skew([[0, 0], [1, 0], [1.5, h], [0.5, h]]) == pytest.approx(2 / 3, abs=1e-14)


def test_trapezoid_with_45_and_135_degree_corners_has_skewness_one_half():
    assert skew([[0, 0], [3, 0], [2, 1], [1, 1]]) == pytest.approx(0.5, abs=1e-14)


def test_reflex_corner_gives_the_negative_skewness_of_its_reflex_angle():
    # dart: the corner at (0.5, 0.5) has interior angle 360 - acos(-0.6) degrees
    theta = 360.0 - math.degrees(math.acos(-0.6))
    expected = 1.0 - (theta - 90.0) / 90.0
    assert expected < 0
    assert skew([[0, 0], [2, 0], [0.5, 0.5], [0, 2]]) == pytest.approx(expected, abs=1e-13)


def test_clockwise_listing_of_a_square_is_inverted_with_skewness_minus_one():
    pts = np.array([[0, 0], [0, 1], [1, 1], [1, 0]], float)
    assert skew(pts) == pytest.approx(-1.0, abs=1e-14)
    assert quality.inverted(pts, ONE)[0]
    assert quality.signed_area(pts, ONE)[0] == pytest.approx(-1.0)


def test_clockwise_listing_of_the_rhombus_is_negative():
    h = math.sqrt(3) / 2
    assert skew([[0.5, h], [1.5, h], [1, 0], [0, 0]]) < 0


def test_area_change_of_an_affine_map_equals_its_determinant():
    rng = np.random.default_rng(0)
    pts = np.array([[0, 0], [1, 0.1], [1.2, 1.0], [-0.1, 0.9], [2.1, 0.0], [2.0, 1.1]])
    quads = np.array([[0, 1, 2, 3], [1, 4, 5, 2]])
    A = np.array([[2.0, 0.5], [0.3, 1.5]])
    moved = pts @ A.T + rng.normal(size=2)
    np.testing.assert_allclose(quality.area_change(pts, moved, quads), np.linalg.det(A), rtol=1e-13)


def test_summary_names_the_worst_element_and_counts_inversions():
    pts = np.array([[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1]], float)
    quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4]])
    moved = pts.copy()
    moved[4] = [2.5, 0.5]                      # pushes node 4 across element 1
    s = quality.summary(pts, moved, quads)
    assert s.n_inverted == 1
    assert s.min_skewness_element == 1
    assert s.min_skewness < 0
    assert s.min_skewness_location == pytest.approx((1.5, 0.5))


convex_quads = st.lists(st.floats(-0.25, 0.25), min_size=8, max_size=8).map(
    lambda d: np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) + np.reshape(d, (4, 2)))


@settings(max_examples=200, deadline=None)
@given(convex_quads, st.floats(0, 2 * math.pi), st.floats(-50, 50), st.floats(-50, 50),
       st.floats(1e-3, 1e3))
def test_skewness_is_invariant_under_rotation_translation_and_uniform_scaling(P, angle, tx, ty, s):
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    moved = s * P @ R.T + [tx, ty]
    assert skew(moved) == pytest.approx(skew(P), abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(convex_quads, st.floats(0, 2 * math.pi), st.floats(-50, 50), st.floats(-50, 50))
def test_area_change_is_one_for_rigid_motions(P, angle, tx, ty):
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    assert quality.area_change(P, P @ R.T + [tx, ty], ONE)[0] == pytest.approx(1.0, abs=1e-11)
