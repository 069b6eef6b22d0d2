"""The iterative flow solve (block-preconditioned GMRES(30)) against the sparse LU, forward and transposed.

Tolerance stated: GMRES to a scaled relative residual ``tol`` gives the
velocity to ``1e3 tol`` and the pressure to ``1e6 tol`` relative to the LU
solution (measured at alpha_max = 1e5: 1e-9 and 2e-6 .. 7e-6 at the forward
solves' 1e-10, 3e-7 and 4e-5 .. 1.1e-3 at the transposed (adjoint) solves'
1e-8); the pressure is the less accurate part because the Schur complement
is ``1/alpha`` small in solid elements.
"""

import numpy as np
import pytest
import scipy.sparse as sp

import tofsi
from tofsi.linalg import DirectSolver, RecyclingSolver
from tofsi.linalg.iterative import TRANSPOSE_TOL, BlockSaddlePreconditioner
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.physics.flow import Flow
from tofsi.physics.flow_preconditioner import flow_preconditioner, schur_parts
from tofsi.fields.flow import FluidSettings

SCENE = "examples/scenes/beam_in_channel_optimization.toml"


def converged_jacobian(alpha_max: float, nx: int = 40, seed: int = 1):
    """The beam scene's flow at a gray random design: (flow, rho, J, a Newton right-hand side)."""
    h = 2.0 / nx
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}", f"fluid.alpha_max={alpha_max}"])
    model = tofsi.Problem(scene).model
    flow = model.flow
    rng = np.random.default_rng(seed)
    rho = model.densities()
    rho = np.where(rho == 1, 1.0, np.clip(0.3 + 0.3 * rng.standard_normal(rho.size), 0, 1))
    w, _ = flow.solve(None, rho)
    J = flow.jacobian(w, None, rho)[0]
    perturbed = w + 0.01 * rng.standard_normal(w.size) * ~flow.bc.is_fixed
    b = -flow.bc.homogenize(flow.residual(perturbed, None, rho))
    return flow, rho, J, b


def relative_errors(flow, x, reference):
    nv = flow.n_velocity
    return (np.linalg.norm((x - reference)[:nv]) / np.linalg.norm(reference[:nv]),
            np.linalg.norm((x - reference)[nv:]) / np.linalg.norm(reference[nv:]))


@pytest.mark.parametrize("alpha_max", [1e3, 1e5])
@pytest.mark.parametrize("pressure_solver", ["amg", "direct"])
def test_fgmres_matches_the_lu_forward_and_transposed(alpha_max, pressure_solver):
    """Both solves to 1e-10 against the LU (the adjoint's own, looser tolerance: the next test)."""
    flow, rho, J, b = converged_jacobian(alpha_max)
    P = flow_preconditioner(flow, J, None, rho, pressure_solver=pressure_solver, transpose_tol=1e-10)
    lu = DirectSolver(J)
    for iterative, direct, tol in ((P.solve, lu.solve, P.tol), (P.solve_transpose, lu.solve_transpose, P.transpose_tol)):
        x = iterative(b)
        assert 5 < P.iterations < 200
        velocity, pressure = relative_errors(flow, x, direct(b))
        assert velocity < 1e3 * tol and pressure < 1e6 * tol, (velocity, pressure)


def test_the_recycling_solver_keeps_the_preconditioner_for_newton_and_adjoint():
    """The preconditioner plugs into RecyclingSolver (``exact = False``): a second, nearby
    Jacobian and its transpose are solved with the first hierarchy, no new one."""
    flow, rho, J, b = converged_jacobian(1e5)
    solver = RecyclingSolver(lambda A: flow_preconditioner(flow, A, None, rho), rtol=1e-10)
    lu = DirectSolver(J)
    x = solver.solve(J, b)
    J2 = J + sp.diags(1e-3 * np.abs(J.diagonal()) * ~flow.bc.is_fixed)   # a nearby matrix
    x2 = solver.solve(J2, b)
    xt = solver.solve_transpose(J, b)
    assert solver.factorizations == 1
    assert np.linalg.norm(J @ x - b) <= 1e-9 * np.linalg.norm(b)
    assert np.linalg.norm(J2 @ x2 - b) <= 1e-9 * np.linalg.norm(b)
    assert relative_errors(flow, xt, lu.solve_transpose(b))[0] < 1e3 * TRANSPOSE_TOL


def test_pinned_pressure_of_a_closed_box_is_kept():
    """A closed cavity (Stokes, all velocities prescribed, one pressure pinned): the pinned
    row is an identity row of J and stays out of the Schur approximation."""
    n = 16
    mesh = StructuredQuadMesh(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    lid = lambda P: np.stack([np.where(P[:, 1] > 1 - 1e-12, 1.0, 0.0), 0 * P[:, 0]], -1)  # noqa: E731
    flow = Flow(mesh, FluidSettings(density=0.0, viscosity=1.0), stokes=True, boundary_velocity=lid)
    w0 = flow.initial()
    J, R = flow.jacobian(w0)
    b = -flow.bc.homogenize(R)
    mass, weights = schur_parts(flow)
    P = BlockSaddlePreconditioner(J, flow.n_velocity, mass, weights, flow.bc.is_fixed)
    x = P.solve(b)
    reference = DirectSolver(J).solve(b)
    velocity, pressure = relative_errors(flow, x, reference)
    assert velocity < 1e-7 and pressure < 1e-6
    assert x[flow.n_velocity] == pytest.approx(reference[flow.n_velocity], abs=1e-12)


def test_schur_parts_are_the_lumped_masses():
    """Hand values on a 2 x 1 mesh of unit squares: corner masses 1/4 per element over mu, and
    the friction mass alpha/9 per Q2 node and element."""
    mesh = StructuredQuadMesh(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0]))
    flow = Flow(mesh, FluidSettings(density=0.0, viscosity=2.0, alpha_max=900.0, alpha_min=0.0), stokes=True)
    mass, weights = schur_parts(flow, rho=np.array([1.0, 1.0]))
    shared = np.isclose(mesh.points[:, 0], 1.0)
    assert np.allclose(mass[shared], 2 * 0.25 / 2.0) and np.allclose(mass[~shared], 0.25 / 2.0)
    free = ~flow.bc.is_fixed[:flow.n_velocity]
    assert free.any()
    values = np.unique(np.round(weights[free], 12))
    assert set(values) <= {round(9 / 900.0, 12), round(9 / 1800.0, 12)}


def test_a_nearly_symmetric_velocity_block_lends_its_hierarchy_to_the_transpose():
    """At Re 1 the velocity block is symmetric to 0.5 %: the transposed solve takes the
    hierarchy of ``A`` (no second setup) and still matches the LU; at Re 10 (5 %) it builds
    the hierarchy of ``A^T``."""
    for density, shared in ((1.0, True), (10.0, False)):
        h = 2.0 / 40
        scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}", f"fluid.density={density}"])
        flow = tofsi.Problem(scene).model.flow
        rho = np.where(flow.mesh.centroids[:, 0] > 1.0, 0.0, 0.4)
        w, _ = flow.solve(None, rho)
        J = flow.jacobian(w, None, rho)[0]
        P = flow_preconditioner(flow, J, None, rho, transpose_tol=1e-8)     # the unscaled residual below
        assert (P.asymmetry <= 1e-2) == shared, P.asymmetry
        b = np.random.default_rng(2).standard_normal(J.shape[0]) * ~flow.bc.is_fixed
        x = P.solve_transpose(b)
        assert np.linalg.norm(J.T @ x - b) <= 1e-6 * np.linalg.norm(b)


@pytest.mark.parametrize("outlet", ["zero-pressure", "traction-free"])
def test_the_preconditioner_holds_the_jacobian_as_its_blocks(outlet):
    """The block preconditioner keeps ``A`` and ``B`` only: the Jacobian's (v, p) block is
    exactly ``B^T`` (on a moved mesh, both outlet forms), and its operator ``[[A, B^T], [B, C]]``
    equals the assembled matrix, forward and transposed."""
    h = 2.0 / 20
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}", f"fluid.outlet={outlet}"])
    flow = tofsi.Problem(scene).model.flow
    rng = np.random.default_rng(5)
    x = 0.01 * h * rng.standard_normal((flow.mesh.n_nodes, 2))
    rho = rng.uniform(0, 1, flow.mesh.n_elements)
    w = flow.initial() + 0.1 * rng.standard_normal(flow.size) * ~flow.bc.is_fixed
    J = flow.jacobian(w, x, rho)[0]
    nv = flow.n_velocity
    assert abs(J[:nv, nv:] - J[nv:, :nv].T).max() == 0.0
    P = flow_preconditioner(flow, J, x, rho)
    v = rng.standard_normal(J.shape[0])
    np.testing.assert_allclose(P.matrix() @ v, J @ v, rtol=0, atol=1e-13 * abs(J).max() * np.abs(v).max())
    np.testing.assert_allclose(P.matrix().T @ v, J.T @ v, rtol=0, atol=1e-13 * abs(J).max() * np.abs(v).max())


@pytest.mark.parametrize("symmetric", [True, False])
def test_the_lean_smoothed_aggregation_is_pyamgs_hierarchy(symmetric):
    """The finest level built without copies of A gives pyamg's own hierarchy (a different
    construction of the same operators): the same levels, P, R and Galerkin matrices to
    round-off, with the same start of the spectral radius estimate (the lean one seeds
    np.random while it builds)."""
    import pyamg
    from tofsi.linalg.amg import ONE_SWEEP, SPECTRAL_SEED, rigid_body_modes, smoothed_aggregation
    K = sp.csr_matrix(pyamg.gallery.linear_elasticity((24, 24))[0])
    A = K if symmetric else (K + 0.2 * (sp.tril(K, -1) - sp.triu(K, 1))).tocsr()   # same pattern, asymmetric
    A.sort_indices()
    points = np.stack(np.meshgrid(np.arange(24.0), np.arange(24.0), indexing="ij"), -1).reshape(-1, 2)
    B = rigid_body_modes(points)
    np.random.seed(SPECTRAL_SEED)
    reference = pyamg.smoothed_aggregation_solver(A, B=B, symmetry="symmetric" if symmetric else "nonsymmetric",
                                                  max_coarse=300, coarse_solver="splu",
                                                  presmoother=ONE_SWEEP[0], postsmoother=ONE_SWEEP[1])
    np.random.seed(3)                        # the caller's random state plays no part
    lean = smoothed_aggregation(A, B, symmetric, ONE_SWEEP)
    assert [level.A.shape for level in lean.levels] == [level.A.shape for level in reference.levels]
    assert len(lean.levels) >= 2
    for mine, theirs in zip(lean.levels[:-1], reference.levels[:-1], strict=True):
        for name in ("P", "R"):
            M, T = sp.csr_matrix(getattr(mine, name)), sp.csr_matrix(getattr(theirs, name))
            assert abs(M - T).max() <= 1e-13 * abs(T).max()
    for mine, theirs in zip(lean.levels[1:], reference.levels[1:], strict=True):
        assert abs(sp.csr_matrix(mine.A) - sp.csr_matrix(theirs.A)).max() <= 1e-12 * abs(theirs.A).max()
    b = np.random.default_rng(0).standard_normal(A.shape[0])
    mine, theirs = lean.aspreconditioner() @ b, reference.aspreconditioner() @ b
    assert np.linalg.norm(mine - theirs) <= 1e-10 * np.linalg.norm(theirs)


@pytest.mark.parametrize("symmetric", [True, False])
def test_a_hierarchy_is_the_same_every_run_whatever_the_callers_random_state(symmetric):
    """pyamg draws each level's spectral-radius start from np.random: unseeded, two builds of
    one matrix differ (in P at about 1e-3, and every iterative solve after them). The hierarchy
    is the same bit for bit on every level, and the caller's random state is left as it was."""
    import pyamg
    from tofsi.linalg.amg import smoothed_aggregation
    K = sp.csr_matrix(pyamg.gallery.linear_elasticity((60, 60))[0])
    A = K if symmetric else (K + 0.2 * (sp.tril(K, -1) - sp.triu(K, 1))).tocsr()
    A.sort_indices()
    builds = []
    for seed in (3, 4):
        np.random.seed(seed)
        builds.append(smoothed_aggregation(A, None, symmetric))
        assert np.random.rand() == np.random.RandomState(seed).rand()      # the caller's stream untouched
    first, second = builds
    assert len(first.levels) >= 3
    for one, other in zip(first.levels, second.levels, strict=True):
        for name in ("A", "P", "R"):
            if hasattr(one, name):
                assert (sp.csr_matrix(getattr(one, name)) != sp.csr_matrix(getattr(other, name))).nnz == 0


@pytest.mark.parametrize("symmetric", [True, False])
def test_the_v_cycle_is_pyamgs_preconditioner_bitwise(symmetric):
    """:func:`tofsi.linalg.amg.v_cycle` applies pyamg's ``aspreconditioner()`` (one V-cycle
    from zero) without its residual norms: the same result bit for bit, on a symmetric and a
    nonsymmetric hierarchy with both smoothers, and on a one-level hierarchy (coarse solve only)."""
    import pyamg
    from tofsi.linalg.amg import ONE_SWEEP, SYMMETRIC_SWEEPS, smoothed_aggregation, v_cycle
    K = sp.csr_matrix(pyamg.gallery.linear_elasticity((60, 60))[0])
    A = K if symmetric else (K + 0.2 * (sp.tril(K, -1) - sp.triu(K, 1))).tocsr()
    A.sort_indices()
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    for smoothers in (ONE_SWEEP, SYMMETRIC_SWEEPS):
        ml = smoothed_aggregation(A, None, symmetric, smoothers)
        assert len(ml.levels) >= 3
        assert np.array_equal(v_cycle(ml)(b), ml.aspreconditioner(cycle="V") @ b)
    small = smoothed_aggregation(A[:200, :200].tocsr(), None, symmetric)
    assert len(small.levels) == 1
    assert np.array_equal(v_cycle(small)(b[:200]), small.aspreconditioner(cycle="V") @ b[:200])


@pytest.mark.parametrize("outlet", ["zero-pressure", "traction-free"])
def test_the_iterative_path_assembles_the_jacobian_as_its_blocks(outlet):
    """On the iterative path the flow's Jacobian is assembled as its blocks ``A``, ``B``: the
    same entries as the assembled CSR matrix of the direct path (on a moved mesh), the same
    products and ``|J| v``, and the preconditioner built from it keeps those very blocks."""
    from tofsi.linalg.block_matrix import SaddlePointMatrix, absolute_product
    h = 2.0 / 20
    settings = [f"mesh.h_min={h}", f"mesh.h_max={h}", f"fluid.outlet={outlet}"]
    direct = tofsi.Problem(tofsi.load_scene(SCENE, settings)).model.flow
    iterative = tofsi.Problem(tofsi.load_scene(SCENE, settings + ["solver.linear_solver=iterative"])).model.flow
    rng = np.random.default_rng(7)
    x = 0.01 * h * rng.standard_normal((direct.mesh.n_nodes, 2))
    rho = rng.uniform(0, 1, direct.mesh.n_elements)
    w = direct.initial() + 0.1 * rng.standard_normal(direct.size) * ~direct.bc.is_fixed
    J = direct.jacobian(w, x, rho)[0]
    blocks = iterative.jacobian(w, x, rho)[0]
    assert isinstance(blocks, SaddlePointMatrix)
    assert abs(blocks.tocsr() - J).max() == 0.0
    v = rng.standard_normal(J.shape[0])
    scale = 1e-13 * abs(J).max() * np.abs(v).max()
    np.testing.assert_allclose(blocks @ v, J @ v, rtol=0, atol=scale)
    np.testing.assert_allclose(blocks.T @ v, J.T @ v, rtol=0, atol=scale)
    np.testing.assert_allclose(absolute_product(blocks, np.abs(v)), abs(J) @ np.abs(v), rtol=1e-13)
    np.testing.assert_allclose(absolute_product(J, np.abs(v), rows=100), abs(J) @ np.abs(v), rtol=1e-13)
    P = flow_preconditioner(iterative, blocks, x, rho)
    assert P.A is blocks.A and P.B is blocks.B
