"""Block Gauss-Seidel preconditioning of coupled Jacobians (tofsi.linalg.BlockGaussSeidel)."""

import functools
import logging

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tofsi.linalg import BlockGaussSeidel, RecyclingSolver

from test_coupled import soft_model

SIZES = (40, 25, 15)


def coupled_matrix(coupling: float, lower_only: bool = False, seed: int = 0) -> sp.csr_matrix:
    """Three nonsymmetric diagonal blocks (diagonally dominant) and off-diagonal couplings of
    the given strength (the block upper triangle left out with ``lower_only``)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i, m in enumerate(SIZES):
        row = []
        for j, n in enumerate(SIZES):
            if i == j:
                B = sp.random(m, n, 0.2, random_state=rng) + sp.eye(m) * 4.0
            elif lower_only and j > i:
                B = None
            else:
                B = coupling * sp.random(m, n, 0.1, random_state=rng)
            row.append(B)
        rows.append(row)
    return sp.bmat(rows, format="csr")


def test_the_solution_and_the_transposed_solution_are_those_of_the_whole_matrix():
    A = coupled_matrix(0.5)
    b = np.random.default_rng(1).normal(size=A.shape[0])
    solver = BlockGaussSeidel(A, SIZES)
    for x, ref in ((solver.solve(b), spla.spsolve(A.tocsc(), b)),
                   (solver.solve_transpose(b), spla.spsolve(A.T.tocsc(), b))):
        assert np.linalg.norm(x - ref) <= 1e-9 * np.linalg.norm(ref)


def test_the_preconditioner_inverts_the_block_lower_triangle_exactly():
    """For a block lower-triangular matrix M = A: M^-1 (A x) = x, and M^-T (A^T x) = x."""
    A = coupled_matrix(2.0, lower_only=True)
    x = np.random.default_rng(2).normal(size=A.shape[0])
    solver = BlockGaussSeidel(A, SIZES)
    assert np.linalg.norm(solver.preconditioner()(A @ x) - x) <= 1e-12 * np.linalg.norm(x)
    assert np.linalg.norm(solver.preconditioner(True)(A.T @ x) - x) <= 1e-12 * np.linalg.norm(x)


def test_refactorized_small_blocks_invert_a_new_block_lower_triangle_and_the_largest_is_kept():
    """Built on one block lower-triangular matrix, refactorized (the blocks smaller than the
    largest) from another with the same largest block: the sweep with the new matrix's couplings
    inverts the new matrix exactly (M = A), the largest block's factors are the same object, and
    without the refactorization it does not (teeth)."""
    from tofsi.linalg import BlockMatrix
    old = coupled_matrix(2.0, lower_only=True, seed=0)
    new = coupled_matrix(2.0, lower_only=True, seed=3)
    new = sp.bmat([[old[:40, :40], None], [new[40:, :40], new[40:, 40:]]], format="csr")  # the flow block kept
    A_old, A_new = BlockMatrix.from_sparse(old, SIZES), BlockMatrix.from_sparse(new, SIZES)
    x = np.random.default_rng(4).normal(size=new.shape[0])
    solver = BlockGaussSeidel(A_old)
    largest = solver.diagonal[0]
    stale = solver.preconditioner(matrix=A_new)(new @ x)
    assert np.linalg.norm(stale - x) > 1e-3 * np.linalg.norm(x)
    assert solver.refactor_small_blocks(A_new) == [1, 2]
    assert solver.diagonal[0] is largest
    assert np.linalg.norm(solver.preconditioner(matrix=A_new)(new @ x) - x) <= 1e-12 * np.linalg.norm(x)
    assert np.linalg.norm(solver.preconditioner(True, matrix=A_new.T)(new.T @ x) - x) <= 1e-12 * np.linalg.norm(x)
    with pytest.raises(ValueError, match="block sizes"):
        solver.refactor_small_blocks(BlockMatrix.from_sparse(old, (40, 15, 25)))


def test_an_adjoint_after_a_far_newton_refactorizes_only_the_small_blocks_and_solves_the_new_transpose():
    """A recycling solver whose block preconditioner was built on one matrix and then served a
    matrix with other small blocks (the same largest: a Newton that moved the structure and the
    mesh far, the flow little) is dearer than a fresh one: its transposed solve refactorizes the
    small blocks only (no new preconditioner, the largest block's factors the same object) and
    returns ``A^-T b`` of the new matrix (SciPy's LU of the whole as the truth)."""
    from tofsi.linalg import BlockMatrix
    old = coupled_matrix(0.5, seed=0)
    rng = np.random.default_rng(3)
    moved = sp.block_diag([sp.csr_matrix((40, 40))] + [3.0 * sp.random(n, n, 0.3, random_state=rng) for n in SIZES[1:]])
    new = (old + moved).tocsr()                            # the small diagonal blocks moved far
    A_old, A_new = BlockMatrix.from_sparse(old, SIZES), BlockMatrix.from_sparse(new, SIZES)
    b = np.random.default_rng(5).normal(size=new.shape[0])
    solver = RecyclingSolver(BlockGaussSeidel)
    solver.solve(A_old, b)                                 # a fresh preconditioner's cost per decade
    solver.solve(A_new, b, rtol=1e-1)                      # a Newton step on the far matrix: dearer
    largest = solver.solver.diagonal[0]
    assert not solver.stale and solver.last_cost - solver.fresh_cost > 0.15 * BlockGaussSeidel.setup_iterations
    x = solver.solve_transpose(A_new, b)
    assert solver.factorizations == 1 and solver.solver.diagonal[0] is largest
    ref = spla.spsolve(new.T.tocsc(), b)
    assert np.linalg.norm(x - ref) <= 1e-9 * np.linalg.norm(ref)


def test_a_ramp_newton_refactorizes_the_small_blocks_once_a_solve_took_more_than_that_costs():
    """``last_excess``: a solve's iterations beyond a fresh preconditioner's over its decades --
    0 for the solve that measured the fresh cost, by definition; more than the small blocks'
    refactorization (``refactor_iterations``) on a matrix whose small blocks moved far, which the
    ramp's Newton then refactorizes (``monolithic.crept``)."""
    from tofsi.coupling.monolithic import crept
    from tofsi.linalg import BlockMatrix
    old = coupled_matrix(0.5, seed=0)
    rng = np.random.default_rng(3)
    moved = sp.block_diag([sp.csr_matrix((40, 40))] + [3.0 * sp.random(n, n, 0.3, random_state=rng) for n in SIZES[1:]])
    A_old, A_new = BlockMatrix.from_sparse(old, SIZES), BlockMatrix.from_sparse((old + moved).tocsr(), SIZES)
    b = np.random.default_rng(5).normal(size=old.shape[0])
    solver = RecyclingSolver(BlockGaussSeidel)
    solver.solve(A_old, b)
    assert solver.last_excess == pytest.approx(0.0, abs=1e-12) and not crept(solver)
    solver.solve(A_new, b, rtol=1e-1)
    assert solver.last_excess > BlockGaussSeidel.refactor_iterations and crept(solver)


def test_block_sizes_that_do_not_make_up_the_matrix_are_refused():
    with pytest.raises(ValueError, match="block sizes"):
        BlockGaussSeidel(coupled_matrix(0.5), (40, 25, 10))


def test_when_gmres_fails_the_whole_matrix_is_factorized_and_the_answer_still_holds(caplog):
    A = coupled_matrix(30.0)                              # couplings far stronger than the blocks
    b = np.random.default_rng(3).normal(size=A.shape[0])
    solver = BlockGaussSeidel(A, SIZES, max_iter=2)
    with caplog.at_level(logging.WARNING):
        x = solver.solve(b)
    assert "factorizing the whole matrix" in caplog.text
    assert np.linalg.norm(A @ x - b) <= 1e-10 * np.linalg.norm(b)


def test_a_recycling_solver_keeps_the_preconditioner_for_a_nearby_matrix():
    A = coupled_matrix(0.5)
    b = np.random.default_rng(4).normal(size=A.shape[0])
    solver = RecyclingSolver(lambda M: BlockGaussSeidel(M, SIZES))
    solver.solve(A, b)
    A2 = A + 0.01 * sp.eye(A.shape[0])
    x = solver.solve(A2, b)
    assert solver.factorizations == 1
    assert np.linalg.norm(A2 @ x - b) <= 1e-9 * np.linalg.norm(b)


def test_two_way_block_and_direct_newton_solves_agree_and_take_the_same_newton_steps():
    """The headline two-way system (flow, structure, Yeoh mesh) solved with either linear
    solver: the same fields to the coupling tolerance, in the same number of Newton steps."""
    states = {}
    for kind in ("block", "direct"):
        model, rho = soft_model("monolithic", f"coupled.jacobian_solver={kind}")
        states[kind] = model.solve(rho)
    a, b = states["block"], states["direct"]
    assert np.abs(a.x).max() > 1e-3
    for f in ("u", "x", "w"):
        ref = getattr(b, f)
        assert np.abs(getattr(a, f) - ref).max() <= 1e-8 * np.abs(ref).max()
    na, nb = (len(s.reports["coupling"]["history"]) for s in (a, b))
    assert na == nb, (na, nb)


def test_a_newton_whose_block_gmres_fails_falls_back_to_the_whole_jacobians_lu(monkeypatch, caplog):
    """A block preconditioner that does nothing, GMRES allowed one iteration: the Newton's first
    step fails, the Newton factorizes the whole Jacobian instead, says so, and lands on the
    same state."""
    import tofsi.coupling.block_system as block_system

    class Useless(BlockGaussSeidel):
        setup_iterations = 0

        def preconditioner(self, transpose=False, matrix=None):
            return np.copy

    model, rho = soft_model("monolithic", "coupled.jacobian_solver=direct")
    reference = model.solve(rho)
    monkeypatch.setattr(block_system, "BlockGaussSeidel", functools.partial(Useless, max_iter=1))
    model, rho = soft_model("monolithic")
    with caplog.at_level(logging.WARNING):
        state = model.solve(rho)
    assert "factorizing the whole Jacobian instead" in caplog.text
    assert any(h.get("fallback") == "direct" for h in state.reports["coupling"]["history"])
    for f in ("u", "x", "w"):
        ref = getattr(reference, f)
        assert np.abs(getattr(state, f) - ref).max() <= 1e-8 * np.abs(ref).max()


def test_a_block_known_by_its_products_solves_like_the_matrix_it_stands_for():
    """A coupling block given as a LinearMap (products only, e.g. a move in increments' tangent):
    products, transposed products, GMRES with the block preconditioner and its transpose give
    what the assembled matrix gives; it remembers its last product (the sweep and the Krylov
    product after it multiply the same vector); the matrix refuses to assemble, and a GMRES that
    fails says so instead of falling back to an LU it cannot make."""
    from tofsi.linalg import BlockMatrix, LinearMap
    A = coupled_matrix(0.5)
    blocks = BlockMatrix.from_sparse(A, SIZES).blocks
    C = blocks[(2, 1)]
    calls = []
    products = LinearMap(C.shape, lambda v: (calls.append(1), C @ v)[1], lambda w: C.T @ w)
    M = BlockMatrix({**blocks, (2, 1): products}, SIZES)
    rng = np.random.default_rng(3)
    v = rng.normal(size=A.shape[0])
    assert np.allclose(M @ v, A @ v, rtol=1e-14, atol=1e-14) and np.allclose(M.T @ v, A.T @ v, atol=1e-14)
    n = len(calls)
    M @ v
    assert len(calls) == n                                   # the same vector: its last product
    b = rng.normal(size=A.shape[0])
    solver = BlockGaussSeidel(M)
    for x, ref in ((solver.solve(b), spla.spsolve(A.tocsc(), b)),
                   (solver.solve_transpose(b), spla.spsolve(A.T.tocsc(), b))):
        assert np.linalg.norm(x - ref) <= 1e-9 * np.linalg.norm(ref)
    assert not M.assembled
    with pytest.raises(TypeError, match="products only"):
        M.tocsr()
    from tofsi.core.errors import NumericalError
    weak = BlockGaussSeidel(M, max_iter=1)
    with pytest.raises(NumericalError, match="did not converge"):
        weak.solve(b)


def test_the_coupled_fields_orderings_factorize_with_less_fill_than_the_old_leaf():
    """Nested dissection cuts down to blocks of 4 grid positions: each field's LU at a two-way
    state has fewer entries than with the old leaf of 32 (flow, structure and mesh: 8-15 % fewer
    on this mesh; the triangular solves of every GMRES sweep follow)."""
    from tofsi.linalg import DirectSolver
    from tofsi.linalg.ordering import nested_dissection
    model, rho = soft_model("monolithic")
    system = model.system_for(model.stage)
    state = model.solve(rho)
    for name in system.cycles[0]:
        A = state.linearizations[name].matrix()
        coords, last = system.by_name[name].ordering_grid()
        ours = DirectSolver(A, perm=system.ordering((name,))).factorization.factor_nnz
        old = DirectSolver(A, perm=nested_dissection(coords, leaf=32, last=last)).factorization.factor_nnz
        assert ours < 0.95 * old, (name, ours, old)
