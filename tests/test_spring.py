"""Spring analogy: element matrices by hand, against the slow oracle, and the GSC/TSC law."""

import math

import numpy as np
import pytest

from movers.base import MotionProblem
from movers.spring import SpringMover, SpringParams
from movers.spring_kernel import quad_force_derivative, quad_stiffness, triangle_stiffness
from reference_kernels import spring_quad
from tofsi.mesh import quality
from tofsi.mesh.structured import StructuredQuadMesh


def test_right_triangle_matrices_by_hand():
    P = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    # lineal: half of 1/L along each edge (each edge is shared by two triangles)
    KL = np.zeros((6, 6))
    e01 = 0.5 * np.array([[1, 0, -1, 0], [0, 0, 0, 0], [-1, 0, 1, 0], [0, 0, 0, 0]])
    e12 = 0.5 / (2 * math.sqrt(2)) * np.array([[1, -1, -1, 1], [-1, 1, 1, -1], [-1, 1, 1, -1], [1, -1, -1, 1]])
    e20 = 0.5 * np.array([[0, 0, 0, 0], [0, 1, 0, -1], [0, 0, 0, 0], [0, -1, 0, 1]])
    for (p, q), blk in (((0, 1), e01), ((1, 2), e12), ((2, 0), e20)):
        idx = [2 * p, 2 * p + 1, 2 * q, 2 * q + 1]
        KL[np.ix_(idx, idx)] += blk
    # torsional: angle gradients worked out by hand, C = 1/sin^2 of the angles (90, 45, 45 deg)
    R = np.array([[1, 1, 0, -1, -1, 0],
                  [0, -1, -0.5, 0.5, 0.5, 0.5],
                  [-1, 0, 0.5, 0.5, 0.5, -0.5]])
    C = np.diag([1.0, 2.0, 2.0])
    np.testing.assert_allclose(triangle_stiffness(P, 0.0)[0], KL, atol=1e-15)
    np.testing.assert_allclose(triangle_stiffness(P, 1.0)[0], KL + R.T @ C @ R, atol=1e-14)
    np.testing.assert_allclose(triangle_stiffness(P, 3.0)[0], KL + 3 * R.T @ C @ R, atol=1e-14)


def test_torsional_rows_are_angle_gradients():
    """R rows equal central differences of the three interior angles."""
    rng = np.random.default_rng(3)
    P = np.array([[0.1, 0.0], [1.2, 0.3], [0.4, 0.9]]) + 0.05 * rng.normal(size=(3, 2))

    def angles(Q):
        Q = Q.reshape(3, 2)
        out = []
        for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
            u, v = Q[j] - Q[i], Q[k] - Q[i]
            out.append(math.atan2(u[0] * v[1] - u[1] * v[0], u @ v))
        return np.array(out)
    h = 1e-6
    grad = np.column_stack([(angles(P.ravel() + h * e) - angles(P.ravel() - h * e)) / (2 * h)
                            for e in np.eye(6)])
    K_T = triangle_stiffness(P[None], 1.0)[0] - triangle_stiffness(P[None], 0.0)[0]
    sin2 = np.sin(angles(P.ravel())) ** 2
    np.testing.assert_allclose(K_T, grad.T @ np.diag(1 / sin2) @ grad, rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize("diagonal", ["1-3", "2-4", "both"])
def test_vectorized_quads_match_the_slow_oracle(diagonal):
    rng = np.random.default_rng(4)
    base = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    Xe = base + 0.2 * rng.uniform(-1, 1, size=(7, 4, 2))
    code = {"1-3": 0, "2-4": 1, "both": 2}[diagonal]
    K = quad_stiffness(Xe, np.full(7, code), torsion_scale=0.7)
    for e in range(7):
        np.testing.assert_allclose(K[e], spring_quad(Xe[e], diagonal, 0.7), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("torsion_scale", [0.0, 0.7])
def test_force_shape_derivative_matches_central_differences_of_the_oracle(torsion_scale):
    """The closed-form ``d(K(X) v)/dX`` (what the increments' tangent and reverse sweeps use)
    against central differences of the slow oracle's forces, every diagonal code."""
    rng = np.random.default_rng(5)
    base = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    Xe = base + 0.2 * rng.uniform(-1, 1, size=(6, 4, 2))
    v = rng.normal(size=(6, 8))
    codes = np.array([0, 1, 2, 0, 1, 2])
    D = quad_force_derivative(Xe, v, codes, torsion_scale)
    h = 1e-6
    for e in range(6):
        diagonal = ("1-3", "2-4", "both")[codes[e]]

        def force(X, e=e, diagonal=diagonal):
            return spring_quad(X.reshape(4, 2), diagonal, torsion_scale) @ v[e]
        fd = np.column_stack([(force(Xe[e].ravel() + h * d) - force(Xe[e].ravel() - h * d)) / (2 * h)
                              for d in np.eye(8)])
        np.testing.assert_allclose(D[e], fd, rtol=1e-7, atol=1e-7 * np.abs(fd).max())


def test_triangle_stiffness_annihilates_rigid_motion():
    P = np.array([[[0.0, 0.0], [2.0, 0.5], [0.7, 1.3]]])
    K = triangle_stiffness(P)[0]
    for mode in ([1, 0] * 3, [0, 1] * 3, np.ravel([[-y, x] for x, y in P[0]])):
        np.testing.assert_allclose(K @ np.asarray(mode, float), 0, atol=1e-13)
    assert np.allclose(K, K.T) and np.linalg.eigvalsh(K).min() > -1e-12


def _square_problem(scale=1.0, n=8):
    mesh = StructuredQuadMesh(scale * np.linspace(0, 1, n + 1), scale * np.linspace(0, 1, n + 1))
    boundary = np.unique(np.concatenate([mesh.side_nodes(s) for s in ("left", "right", "bottom", "top")]))
    problem = MotionProblem.from_mesh(mesh, np.arange(mesh.n_elements), boundary)
    u = np.zeros((mesh.n_nodes, 2))
    top = mesh.side_nodes("top")
    u[top, 0] = 0.3 * scale * np.sin(np.pi * mesh.points[top, 0] / scale)     # shear the lid
    return problem, u


@pytest.mark.parametrize("gsc", [1e-3, 1e2])
def test_geometric_scale_equals_inverse_torsion_scale(gsc):
    """Scaling geometry and motion by GSC gives the same mesh as TSC = 1/GSC (exactly)."""
    big, u_big = _square_problem(gsc)
    ref, u_ref = _square_problem(1.0)
    x_big = SpringMover(SpringParams(diagonals="both", increments=3)).move(big, u_big).displacement
    x_tsc = SpringMover(SpringParams(diagonals="both", increments=3, torsion_scale=1 / gsc)).move(ref, u_ref).displacement
    # exact in exact arithmetic; the increments are solved to a relative 1e-10
    np.testing.assert_allclose(x_big / gsc, x_tsc, rtol=0, atol=1e-8 * np.abs(x_tsc).max())


def test_selective_diagonals_keep_the_better_quad_per_element():
    """Each quad keeps the diagonal whose first increment leaves it with the higher skewness:
    the two trial increments redone here with fixed diagonals 1-3 and 2-4, quad by quad."""
    problem, u = _square_problem(1.0)
    mover = SpringMover(SpringParams(diagonals="selective", increments=4))
    result = mover.move(problem, u)
    codes = result.cell_data["diagonal"]
    trial = [quality.skewness(problem.points + SpringMover(SpringParams(diagonals=d, increments=1))
                              .move(problem, u / 4).displacement, problem.quads) for d in ("1-3", "2-4")]
    clear = np.abs(trial[1] - trial[0]) > 1e-9                 # leave out exact ties (symmetry)
    assert clear.sum() > 0.9 * len(codes)
    np.testing.assert_array_equal(codes[clear], np.where(trial[1] > trial[0], 1, 0)[clear])
    assert 0 < codes.mean() < 1                       # the sheared lid uses both diagonals
    assert result.report.linear_solves == 4 + 2      # two trial increments, then the motion
