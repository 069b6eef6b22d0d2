"""Every sparse direct backend against SuperLU on the project's own systems.

Truths: SuperLU (the reference backend) and the residual of the system
itself. Each backend solves the constrained Navier-Stokes Jacobian (a
saddle-point system with Brinkman rows of 1e5 next to viscous rows of 1),
the clamped elasticity stiffness and a random unsymmetric matrix, forward
and transposed, to 1e-10 of SuperLU's answer; the analysis is done once per
pattern (counters); optional backends are skipped with the reason.
"""

from __future__ import annotations

import gc
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import tofsi
from tofsi.coupling.coupled import CoupledModel
from tofsi.core.errors import InputError
from tofsi.linalg import AMGSolver, DirectSolver, RecyclingSolver, backends, nested_dissection, superlu
from tofsi.physics.flow import Flow
from tofsi.physics.structure import Structure

OPTIONAL = [b for b in backends.MODULES if b != "superlu"]


def backend_or_skip(name: str):
    why = backends.unavailable(name)
    if why is not None:
        pytest.skip(f"backend {name} not available: {why}")
    return backends.get_backend(name)


@pytest.fixture(scope="module")
def systems():
    """(name, matrices with one pattern, ordering) of the systems the solvers meet."""
    scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml",
                             ["mesh.h_min=0.08", "mesh.h_max=0.08"])
    model = tofsi.Problem(scene).model
    flow, structure = model.flow, model.structure
    rng = np.random.default_rng(3)
    rho = model.densities()
    flows = []
    for k in range(2):
        r = np.clip(rho + 0.3 * k * rng.standard_normal(rho.size), 0, 1)
        w = flow.initial() + k * 0.1 * rng.standard_normal(flow.size) * ~flow.bc.is_fixed
        flows.append(flow.jacobian(w, None, r, flow.density)[0])
    flow_perm = nested_dissection(flow.grid(), last=np.arange(flow.size) >= flow.n_velocity)
    stiff = [structure.stiffness(np.clip(rho + 0.2 * k, 0, 1)) for k in range(2)]
    n = 300
    rand = [(sp.random(n, n, density=0.02, random_state=k) + 5 * sp.eye(n)).tocsr() for k in range(2)]
    rand[1] = sp.csr_matrix((rand[0].data * (1 + 0.1 * rng.random(rand[0].nnz)),
                             rand[0].indices, rand[0].indptr), shape=rand[0].shape)
    return [("flow", flows, flow_perm), ("structure", stiff, structure_perm(structure)),
            ("random", rand, None)]


def structure_perm(structure: Structure) -> np.ndarray:
    m = structure.mesh
    i = np.tile(np.arange(m.nx + 1), m.ny + 1)
    j = np.repeat(np.arange(m.ny + 1), m.nx + 1)
    return nested_dissection(np.repeat(np.column_stack([2 * i, 2 * j]), 2, axis=0))


@pytest.mark.parametrize("name", list(backends.MODULES))
def test_backend_matches_superlu_forward_and_transposed(systems, name):
    backend_or_skip(name)
    rng = np.random.default_rng(0)
    for label, matrices, perm in systems:
        for A in matrices:
            b = rng.standard_normal(A.shape[0])
            ref = DirectSolver(A, perm=perm, backend="superlu")
            got = DirectSolver(A, perm=perm, backend=name)
            for solve, ref_solve, M in ((got.solve, ref.solve, A), (got.solve_transpose, ref.solve_transpose, A.T)):
                x, x_ref = solve(b), ref_solve(b)
                assert np.linalg.norm(M @ x_ref - b) <= 1e-11 * np.linalg.norm(b), label
                assert np.linalg.norm(x - x_ref) <= 1e-10 * np.linalg.norm(x_ref), (label, name)


@pytest.mark.parametrize("name", list(backends.MODULES))
def test_analysis_once_per_pattern(systems, name):
    backend = backend_or_skip(name)
    backends.clear_cache()
    _, (A0, A1), perm = systems[0]
    before = (backend.analyses, backend.factorizations)
    b = np.ones(A0.shape[0])
    solver = None
    for A in (A0, A1, A0):                    # Newton steps / design iterations: values change
        solver = None                         # the previous factorization is released first
        solver = DirectSolver(A, perm=perm, backend=name)
        assert np.linalg.norm(A @ solver.solve(b) - b) <= 1e-10 * np.linalg.norm(b)
    assert backend.analyses - before[0] == 1                   # one pattern, one analysis
    assert backend.factorizations - before[1] == 3
    DirectSolver(systems[1][1][0], perm=systems[1][2], backend=name)
    assert backend.analyses - before[0] == 2                   # a new pattern is analysed
    DirectSolver(A0, perm=perm[::-1].copy(), backend=name)
    assert backend.analyses - before[0] == 3                   # another ordering: another analysis
    # factorizations alive at the same time each keep their own values
    solvers = [DirectSolver(A, perm=perm, backend=name) for A in (A0, A1, A0)]
    for S, A in zip(solvers, (A0, A1, A0), strict=True):
        assert np.linalg.norm(A @ S.solve(b) - b) <= 1e-10 * np.linalg.norm(b)


def test_pattern_content_not_identity_keys_the_analysis(systems):
    """A matrix with the same values but a different pattern (an explicit zero moved) is
    analysed anew: the cache compares the pattern itself."""
    backend = backends.get_backend("superlu")
    backends.clear_cache()
    A = systems[2][1][0].copy()
    DirectSolver(A, backend="superlu")
    B = A.tolil()
    B[0, A.shape[0] - 1] = 1e-3                                # a new entry: a new pattern
    count = backend.analyses
    x = DirectSolver(B.tocsr(), backend="superlu").solve(np.ones(A.shape[0]))
    assert backend.analyses == count + 1
    assert np.linalg.norm(B @ x - 1) <= 1e-10 * np.sqrt(A.shape[0])


def test_pardiso_slots_never_overwrite_a_live_factorization(systems):
    backend_or_skip("pardiso")
    from tofsi.linalg import pardiso
    backends.clear_cache()
    _, (A0, A1), perm = systems[0]
    b = np.linspace(0, 1, A0.shape[0])
    kept = [DirectSolver(A0 if k % 2 == 0 else A1, perm=perm, backend="pardiso")
            for k in range(pardiso.SLOTS + 2)]            # more than one analysis holds
    for k, S in enumerate(kept):
        A = A0 if k % 2 == 0 else A1
        assert np.linalg.norm(A @ S.solve(b) - b) <= 1e-10 * np.linalg.norm(b)
    del kept, S
    gc.collect()


def test_recycling_solver_on_every_backend(systems):
    """The Newton-and-adjoint pattern: GMRES preconditioned by an older factorization gives the
    new matrix's answer, forward and transposed, with whichever backend the default names."""
    _, (A0, A1), perm = systems[0]
    b = np.random.default_rng(1).standard_normal(A0.shape[0])
    ref = DirectSolver(A1, perm=perm, backend="superlu")
    for name in backends.available():
        rec = RecyclingSolver(lambda A, name=name: DirectSolver(A, perm=perm, backend=name))
        rec.refresh(A0)
        x, xt = rec.solve(A1, b), rec.solve_transpose(A1, b)
        assert np.linalg.norm(A1 @ x - b) <= 1.01e-10 * np.linalg.norm(b)
        assert np.linalg.norm(A1.T @ xt - b) <= 1.01e-10 * np.linalg.norm(b)
        assert np.linalg.norm(x - ref.solve(b)) <= 1e-8 * np.linalg.norm(x)


def test_unknown_or_missing_backend_is_an_input_error():
    with pytest.raises(InputError, match="solver.linear_solver"):
        backends.set_default("cholmod")
    missing = [b for b in OPTIONAL if backends.unavailable(b) is not None]
    for name in missing:
        with pytest.raises(InputError, match="not"):
            backends.set_default(name)
    assert backends.default() == "superlu"


def test_auto_picks_the_fastest_available():
    assert backends.resolve("auto") == backends.available()[0]
    assert "superlu" in backends.available()
    assert backends.available() == [b for b in backends.AUTO_ORDER if backends.unavailable(b) is None]


def test_scene_solver_table(tmp_path):
    scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml",
                             ["solver.linear_solver=auto", "solver.blas_threads=1"])
    assert scene.solver.linear_solver == "auto"
    with pytest.raises(InputError, match="solver.linear_solver"):
        tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml",
                         ["solver.linear_solver=umfpack"])


def test_flow_solve_is_the_same_on_every_backend():
    """A whole Navier-Stokes solve (Newton with recycled factorizations) agrees across backends."""
    scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml",
                             ["mesh.h_min=0.1", "mesh.h_max=0.1"])
    model = tofsi.Problem(scene).model
    rho = model.densities()
    results = {}
    previous = backends.default()
    try:
        for name in backends.available():
            backends.set_default(name)
            flow = Flow(model.mesh, scene.fluid)
            results[name] = flow.solve(None, rho)[0]
    finally:
        backends.set_default(previous)
    ref = results["superlu"]
    for name, w in results.items():
        assert np.linalg.norm(w - ref) <= 1e-9 * np.linalg.norm(ref), name


def test_petsc_on_two_ranks_equals_the_serial_solve(tmp_path):
    """``mpiexec -n 2``: MUMPS factorizes across two processes, each owning half the rows;
    the coupled state equals the serial SuperLU one to 1e-10."""
    backend_or_skip("petsc")
    mpiexec = shutil.which("mpiexec")
    if mpiexec is None:
        pytest.skip("mpiexec not found")
    root = Path(__file__).resolve().parents[1]
    sets = ["mesh.h_min=0.1", "mesh.h_max=0.1"]
    out = tmp_path / "mpi.npz"
    env = {**os.environ, "PYTHONPATH": str(root), "OMPI_MCA_rmaps_base_oversubscribe": "1"}
    subprocess.run([mpiexec, "--allow-run-as-root", "-n", "2", sys.executable, "tests/mpi_solve.py",
                    str(out), *sets], cwd=root, env=env, check=True, timeout=300)
    got = np.load(out)
    assert int(got["ranks"]) == 2 and got["rows"].min() > 0
    scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml", sets)
    model = CoupledModel(scene)
    state = model.solve(model.densities())
    for name in ("w", "u"):
        ref = getattr(state, name)
        assert np.linalg.norm(got[name] - ref) <= 1e-10 * np.linalg.norm(ref), name


def test_resume_is_bitwise_exact_with_pardiso(tmp_path):
    """PARDISO's analysis depends on the pattern only and MKL runs in its reproducible mode
    (MKL_CBWR=AUTO,STRICT), so an interrupted and resumed optimization repeats the full one
    bit for bit, as with SuperLU (tests/test_optimize.py)."""
    backend_or_skip("pardiso")
    from tofsi.optimization.optimize import Optimizer
    sets = ["mesh.h_min=0.05", "mesh.h_max=0.05", "design.filter_radius=0.15", "optimizer.max_iter=8",
            "design.stage_iterations=4", "solver.linear_solver=pardiso", "solver.threads=2"]

    def run(output, on_iteration=None, resume=False):
        scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml", sets)
        opt = Optimizer(tofsi.Problem(scene), output, on_iteration=on_iteration)
        opt.run(resume=resume)
        return opt

    try:
        full = run(tmp_path / "full")

        def interrupt(it):
            if it.iteration == 5:
                raise KeyboardInterrupt
        with pytest.raises(KeyboardInterrupt):
            run(tmp_path / "cut", on_iteration=interrupt)
        resumed = run(tmp_path / "cut", resume=True)
    finally:
        backends.set_default("superlu")
    key = lambda h: (h.iteration, h.objective, h.volume, h.constraint, h.change)
    assert [key(h) for h in resumed.history] == [key(h) for h in full.history]
    np.testing.assert_array_equal(np.load(tmp_path / "cut" / "design.npy"),
                                  np.load(tmp_path / "full" / "design.npy"))


def test_amg_hierarchy_preconditions_nearby_matrices_until_it_goes_stale():
    """Slowly changing elasticity matrices: one V-cycle of an older AMG hierarchy preconditions
    CG on each, every answer is the new matrix's (against SuperLU), one hierarchy serves the
    nearby matrices, and a matrix far from them gets a new one."""
    scene = tofsi.load_scene("examples/scenes/beam_in_channel_optimization.toml",
                             ["mesh.h_min=0.04", "mesh.h_max=0.04"])
    structure = tofsi.Problem(scene).model.structure
    rho = np.full(structure.mesh.n_elements, 0.5)
    nearby = [structure.stiffness(rho * (1 + 0.02 * k)) for k in range(5)]
    far = rho.copy()
    far[structure.mesh.centroids[:, 0] > 1.0] = 1.0                       # one half 8x stiffer (p = 3)
    rec = RecyclingSolver(lambda A: AMGSolver(A, tol=1e-10))
    b = np.random.default_rng(4).standard_normal(nearby[0].shape[0])
    b[structure.bc.fixed] = 0.0
    for K in nearby:
        x = rec.solve(K, b)
        assert np.linalg.norm(K @ x - b) <= 1.01e-10 * np.linalg.norm(b)
        ref = DirectSolver(K).solve(b)
        assert np.linalg.norm(x - ref) <= 1e-7 * np.linalg.norm(ref)
    assert rec.factorizations == 1
    K = structure.stiffness(far)
    x = rec.solve(K, b)
    assert rec.factorizations == 2
    assert np.linalg.norm(K @ x - b) <= 1.01e-10 * np.linalg.norm(b)


def test_a_direct_solve_spends_no_refinement_past_round_off():
    """A SIMP-like contrast (coefficients 1e-9 .. 1 on a 1D Laplacian) leaves |r| / |b| ~ 1e-5,
    far above the 1e-12 refinement goal, at a componentwise backward error of 1e-16: refining
    cannot gain a digit, so the solve is one triangular solve pair (it was three). Where the
    backward error is large the refinement still runs (a perturbed factorization)."""
    from tofsi.linalg.direct import ROUND_OFF
    rng = np.random.default_rng(0)
    n = 4000
    k = 10 ** rng.uniform(-9, 0, n + 1)
    A = sp.diags([-k[1:-1], k[:-1] + k[1:], -k[1:-1]], [-1, 0, 1], format="csr")
    b = rng.standard_normal(n)
    solver = DirectSolver(A, backend="superlu")
    exact = solver.factorization

    class Counting:
        calls = 0

        def solve(self, rhs, trans="N"):
            Counting.calls += 1
            return exact.solve(rhs, trans)
    solver.factorization = Counting()
    x = solver.solve(b)
    r = b - A @ x
    assert np.linalg.norm(r) > 1e3 * solver.refine_tol * np.linalg.norm(b)     # the goal is out of reach
    assert solver.backward_error(b, x, r, "N") <= ROUND_OFF and Counting.calls == 1

    class Perturbed:                                       # factors of a 1 % different matrix
        inner = DirectSolver(A + 0.01 * sp.diags(A.diagonal()), backend="superlu").factorization

        def solve(self, rhs, trans="N"):
            Counting.calls += 1
            return Perturbed.inner.solve(rhs, trans)
    Counting.calls = 0
    solver.factorization = Perturbed()
    solver.solve(b)
    assert Counting.calls == 3                             # refined twice: the backward error was large



def resident_bytes() -> int:
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")


RELEASE_CHECK = """
import numpy as np
from pathlib import Path
from tofsi.linalg import superlu
resident = lambda: int(Path("/proc/self/statm").read_text().split()[1]) * 4096
big = np.ones(2**21)         # 16 MB, freed from its own mapping: glibc's heap then serves mid-size arrays
del big
pairs = [(np.ones(2**20), np.ones(2**13)) for _ in range(30)]    # 8 MB each, a small one between
pins = [small for _, small in pairs]
del pairs
written = resident()
superlu.release_free_pages()
print((written - resident()) / 1e6)
"""


@pytest.mark.skipif(not superlu.GLIBC or not Path("/proc/self/statm").exists(),
                    reason="glibc's heap and /proc's resident set")
def test_release_free_pages_gives_the_heaps_written_free_memory_back():
    """Memory the heap has written and freed stays resident, and glibc hands it to the next
    allocations: SuperLU's factors, sized from a fill estimate 5-14 times what they use, would
    make all of it resident again (a move in increments keeps one per increment; issue 32's
    spring grew to 8 GB at 80 x 40). :func:`~tofsi.linalg.superlu.release_free_pages` gives it
    back first: 240 MB written and freed between live arrays leave the resident set (a fresh
    process: the heap's state is its own)."""
    out = subprocess.run([sys.executable, "-c", RELEASE_CHECK], capture_output=True, text=True, check=True)
    assert float(out.stdout) > 200, out.stdout
