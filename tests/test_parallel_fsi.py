"""The two-way problem and the movers by slabs on two MPI ranks (PETSc), against the serial ones.

Skipped with the reason where petsc4py or mpiexec is absent (the default
install is pip-only; ``docs/parallel.md`` tells how to get them).
"""

import json
from pathlib import Path

import numpy as np
import pytest
from two_ranks import run_on_two_ranks

import tofsi
from tofsi.parallel.partition import SlabPartition

FSI = "examples/scenes/beam_in_channel_optimization_fsi.toml"
FSI_SETS = ["mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.newton_tol=1e-12", "coupled.tol=1e-11",
            "mover.yeoh.newton_tol=1e-13"]


@pytest.mark.parametrize("stage, mover", [
    (0, []), (4, []),
    (4, ["mover.name=linear", "structure.youngs_modulus=2e4"]),
    (4, ["mover.name=spring", "mover.spring.increments=3"])])
def test_fsi_gradient_on_two_ranks_equals_the_serial_problem(tmp_path, stage, mover):
    """The headline two-way scene (Yeoh mover with density-grown stiffened layers, E = 5 kPa;
    also linear elasticity with Jacobian stiffening, E = 20 kPa -- at 5 kPa its mesh folds at
    the wall's tip, serially too --, and the spring analogy in 3 increments, a path-dependent
    move), 20 x 10 elements, at its first stage (one-way, beta 1) and its last (two-way,
    beta 16), two designs (a wall with noise, the second warm-started): on two ranks (the flow,
    the structure and the movers by slabs -- Yeoh and linear by their residual, the spring's
    increments each by slabs and its reverse sweep likewise --, the fluid load and coupling
    partials on each rank's elements; IQN-ILS forward, reverse sweeps with GMRES for the
    adjoint) the compliance and its gradient equal the serial ``Problem``'s (monolithic Newton,
    LU adjoint) to 1e-8 relative (measured 1.8e-9 and 1.8e-10 with Yeoh by slabs, 4.2e-10 and
    1.6e-10 linear, 8.3e-10 and 2.7e-10 with the spring in increments by slabs, 1e-11 one-way),
    the states to 1e-9."""
    sets = [*FSI_SETS, *mover]
    out = tmp_path / "fsi.npz"
    run_on_two_ranks("tests/mpi_fsi_problem.py", FSI, str(out), "gamg", str(stage), *sets)
    got = np.load(out)
    from tofsi.coupling.coupled import continuation
    scene = tofsi.load_scene(FSI, sets)
    problem = tofsi.Problem(scene)
    problem.set_stage(continuation(scene, stage))
    for k in range(2):
        gamma = got[f"gamma{k}"]
        f, df = problem.evaluate(gamma)
        g, dg = problem.constraints(gamma)
        assert abs(float(got[f"f{k}"]) - f) <= 1e-8 * abs(f)
        assert np.linalg.norm(got[f"df{k}"] - df) <= 1e-8 * np.linalg.norm(df)
        assert np.allclose(got[f"g{k}"], g, rtol=1e-12, atol=1e-14)
        state = problem.solve(gamma)
        assert (state.x is not None) == (stage == 4) == (f"x{k}" in got)
        for name in ("w", "u", "x")[:3 if stage == 4 else 2]:
            want = state.fields[name]
            assert np.linalg.norm(got[f"{name}{k}"] - want) <= 1e-9 * np.linalg.norm(want), name


def test_tofsi_optimize_under_mpiexec_follows_the_serial_optimizer_on_the_fsi_scene(tmp_path):
    """``mpiexec -n 2 tofsi optimize`` of the headline two-way scene (20 x 10): its first stages
    are one-way, so 3 MMA evaluations there run through the distributed FSI problem (rank 0's
    optimizer, the flow by slabs, the load by slabs, the structure replicated) and follow the
    serial optimizer to 1e-6."""
    from tofsi.optimization.optimize import Optimizer
    sets = [*FSI_SETS, "design.stage_iterations=2", "optimizer.max_iter=3"]
    out = tmp_path / "distributed"
    run_on_two_ranks("-m", "tofsi.cli", "optimize", FSI, *[a for s in sets for a in ("--set", s)],
                     "--output", str(out), "-q", "--allow-unphysical")       # a 3-iteration design: gray
    serial = Optimizer(tofsi.Problem(tofsi.load_scene(FSI, sets)), tmp_path / "serial")
    serial.run()
    import json
    rows = json.loads((out / "history.json").read_text())
    assert len(rows) == len(serial.history) == 3
    for got, want in zip(rows, serial.history, strict=True):
        assert got["stage"] == want.stage
        assert abs(got["objective"] - want.objective) <= 1e-6 * abs(want.objective)
        assert abs(got["change"] - want.change) <= 1e-6 * max(want.change, 1e-3)
    assert np.max(np.abs(np.load(out / "design.npy") - np.load(serial.output / "design.npy"))) <= 1e-6


@pytest.mark.parametrize("sets, key", [
    (["structure.model=neo-hookean"], "structure.model"),
    (["design.objective=dissipation"], "design.objective"),
    (["design.min_skewness=0.2"], "design.min_skewness"),
])
def test_the_distributed_fsi_problem_refuses_what_it_cannot_do_before_needing_petsc(sets, key):
    """Finite strain, another objective, a mesh-quality constraint: refused by name before
    anything is built, with or without petsc4py."""
    from tofsi.core.errors import InputError
    from tofsi.parallel.fsi_problem import DistributedFsiProblem
    loaded = tofsi.load_scene(FSI, ["mesh.h_min=0.1", "mesh.h_max=0.1", *sets])
    with pytest.raises(InputError, match=key):
        DistributedFsiProblem(loaded)


@pytest.mark.parametrize("mover", [[], ["mover.name=linear"], ["mover.name=spring"]])
def test_mover_by_slabs_equals_the_serial_mover(tmp_path, mover):
    """The headline scene's Yeoh mover (density blend, stiffened layers grown from the
    densities), its linear mover and its spring analogy in one increment, 20 x 10 elements, at a wall design and a prescribed
    displacement bending it 8 cm downstream: on two ranks (element kernels on each rank's
    quads, the tangent by MUMPS across the ranks, Newton with load steps) the motion equals
    the serial mover's move, and the transposed solve and partials at it the serial
    ``MeshMotion``'s (``transposed_solve``, ``partials_transpose``), to 1e-10 relative (measured:
    Yeoh 3.4e-13 for x, 7.1e-13 for lam, 9.7e-13 for rho; linear and spring 2e-15 at most)."""
    sets = ["mesh.h_min=0.1", "mesh.h_max=0.1", "mover.yeoh.newton_tol=1e-13", *mover]
    out = tmp_path / "mover.npz"
    run_on_two_ranks("tests/mpi_slab_mover.py", FSI, str(out), *sets)
    got = np.load(out)
    motion = tofsi.Problem(tofsi.load_scene(FSI, sets)).model.motion
    rho, u = got["rho"], got["u"]
    x = motion.move(u, rho).displacement.ravel()
    assert np.abs(x).max() > 0.01                                     # the mesh moved
    assert np.linalg.norm(got["x"] - x) <= 1e-10 * np.linalg.norm(x)
    lam = motion.transposed_solve(x, rho, got["rhs"])
    u_bar, rho_bar = motion.partials_transpose(x, u, rho, lam)
    for name, want in (("lam", lam), ("u_bar", u_bar), ("rho_bar", rho_bar)):
        assert np.linalg.norm(got[name] - want) <= 1e-10 * np.linalg.norm(want), name


@pytest.mark.parametrize("mover", [
    ["mover.name=spring", "mover.spring.increments=4"],
    ["mover.name=spring", "mover.spring.increments=3", "mover.spring.diagonals=selective"],
    ["mover.name=spring", "mover.spring.increments=4", "mover.spring.scheme=midpoint"],
    ["mover.name=spring", "mover.spring.increments=3", "mover.spring.scheme=midpoint",
     "mover.spring.first_increment=0.1"],
    ["mover.name=linear", "mover.linear.increments=3"]])
def test_a_move_in_increments_by_slabs_equals_the_serial_move(tmp_path, mover):
    """The headline scene's spring analogy in 4 increments (both diagonals), in 3 with the
    selective diagonals (two trial increments, each quad choosing on its rank), in 4 with each
    increment's stiffness at its extrapolated midpoint (``scheme = "midpoint"``), in 3 such with
    the first 0.1 of the motion (the large scene's, ``first_increment``) and linear
    elasticity in 3, 20 x 10 elements, the wall design bent 8 cm downstream: on two ranks (each
    increment's element matrices on the rank's quads, its system by MUMPS across the ranks) the
    motion equals the serial mover's move, and the tangent sweep along a random ``u_dot`` and the
    reverse sweep of a random ``x_bar`` (to ``u`` and ``rho``) the serial ``MeshMotion``'s
    ``jvp`` and ``vjp``, to 1e-10 relative (measured: at most 5e-14 for x, 2e-13 for the
    sweeps); the reverse sweep once more after another move has reassembled the matrices
    gives the same to 1e-12."""
    sets = ["mesh.h_min=0.1", "mesh.h_max=0.1", *mover]
    out = tmp_path / "mover.npz"
    run_on_two_ranks("tests/mpi_slab_mover.py", FSI, str(out), *sets)
    got = np.load(out)
    motion = tofsi.Problem(tofsi.load_scene(FSI, sets)).model.motion
    assert motion.path_dependent
    rho, u = got["rho"], got["u"]
    result = motion.move(u, rho)
    x = result.displacement.ravel()
    assert np.abs(x).max() > 0.01 and int(got["increments"]) == motion.mover.params.increments
    assert np.linalg.norm(got["x"] - x) <= 1e-10 * np.linalg.norm(x)
    u_bar, rho_bar = motion.vjp(result, got["rhs"].reshape(-1, 2), rho)
    x_dot = motion.jvp(result, got["u_dot"])
    for name, want in (("x_dot", x_dot), ("vjp_u", u_bar), ("vjp_rho", rho_bar), ("again_u", u_bar),
                       ("again_rho", rho_bar)):
        assert np.linalg.norm(got[name] - want) <= 1e-10 * np.linalg.norm(want), name
    for name in ("u", "rho"):
        assert np.linalg.norm(got[f"again_{name}"] - got[f"vjp_{name}"]) <= 1e-12 * np.linalg.norm(got[f"vjp_{name}"])
    for name, want in (("u_bar", -got["vjp_u"]), ("rho_bar", -got["vjp_rho"])):   # the explicit map's partials
        assert np.linalg.norm(got[name] - want) <= 1e-12 * np.linalg.norm(want), name


def test_a_failing_mover_by_slabs_fails_on_every_rank_alike(tmp_path):
    """One Newton iteration and no cutback cannot move the Yeoh mesh 8 cm: every rank raises
    the same NumericalError, with the mover's diagnosis (no rank left waiting)."""
    sets = ["mesh.h_min=0.1", "mesh.h_max=0.1", "mover.yeoh.newton_tol=1e-13", "mover.yeoh.max_newton=1",
            "mover.yeoh.max_cutbacks=0"]
    out = tmp_path / "mover.npz"
    run_on_two_ranks("tests/mpi_slab_mover.py", FSI, str(out), *sets)
    messages = [Path(f"{out}.rank{r}.txt").read_text() for r in range(2)]
    assert messages[0] == messages[1]
    assert "yeoh mover (by slabs): no convergence beyond load 0 after 1 cutbacks" in messages[0]


@pytest.mark.parametrize("amplitude, factor, mover, diagnosis", [
    ("1.0", "1", ["mover.name=spring", "mover.spring.increments=2"],
     "spring mover (by slabs): 11 inverted element(s); worst element 141 (skewness -1.9) at (1.46, 0.65) m"),
    ("2.0", "1", ["mover.name=linear", "mover.linear.increments=3", "mover.linear.chi=0.5"],
     "linear mover (by slabs): the element matrices of 2 quad(s) are not finite at the increment's stiffness "
     "point (elements 117, 138: inverted or degenerate there) at increment 2 of 3; after increment 1 the worst "
     "element is 139 (skewness -1.99, 3 inverted) at (1.27, 0.65) m"),
    ("0.08", "nan", ["mover.name=spring", "mover.spring.increments=2"],
     "spring mover (by slabs): prescribed displacement contains NaN or inf")])
def test_a_failing_move_in_increments_by_slabs_fails_on_every_rank_alike(tmp_path, amplitude, factor, mover, diagnosis):
    """Moves in increments by slabs that fail, 20 x 10 elements, the wall design: bent 1 m, the spring's
    mesh in 2 increments ends with 11 inverted quads; bent 2 m, linear elasticity in 3 with ``chi = 1/2``
    inverts 3 quads in its first increment, so the second's element matrices (``det J^(1/2)``) are NaN
    on the quads of rank 1's slab only, which every rank learns before the solve across them; a NaN
    motion is refused before any solve. Every rank raises the same NumericalError with its diagnosis
    (the worst element and where), none is left waiting (the run ends within its timeout), and the
    same mover then moves the 0.08 m bend as the serial mover does, to 1e-10."""
    sets = ["mesh.h_min=0.1", "mesh.h_max=0.1", *mover]
    out = tmp_path / "failure"
    run_on_two_ranks("tests/mpi_slab_failure.py", FSI, str(out), amplitude, factor, *sets)
    records = [json.loads(Path(f"{out}.rank{r}.json").read_text()) for r in range(2)]
    for record in records:
        record["diagnostic"].get("report", {}).pop("wall_time_s", None)      # each rank's clock
    assert records[0] == records[1]
    assert records[0]["message"] == diagnosis
    bad = records[0]["diagnostic"].get("non_finite_elements")
    if bad is not None:                                   # a fault on one rank's quads only
        flow = tofsi.Problem(tofsi.load_scene(FSI, sets)).model.flow
        slabs = [set(SlabPartition.of(flow, r, 2).elements.tolist()) for r in range(2)]
        assert set(bad) <= slabs[1] and not set(bad) & slabs[0]
    again = np.load(f"{out}.npz")
    x = tofsi.Problem(tofsi.load_scene(FSI, sets)).model.motion.move(again["u"], again["rho"]).displacement.ravel()
    assert np.abs(x).max() > 0.01
    assert np.linalg.norm(again["x"] - x) <= 1e-10 * np.linalg.norm(x)


def test_a_slab_matrix_recovers_from_a_failed_factorization(tmp_path):
    """Linear elasticity's matrix of the FSI scene's moving mesh (20 x 10), one quad's element
    matrix NaN on rank 1 only: its solve across the ranks fails on both with the same error
    (MUMPS's factorization fails: KSP reason -11); assembled right, the same matrix then solves
    (GMRES to 1e-8 with its new factors, then exactly) as a matrix that never failed, to 1e-12
    (MUMPS keeps a failed analysis for a matrix of the same pattern: the solver is discarded), also
    transposed; assembled doubled after its factors expire (a new design), it solves with
    ``rtol`` as a matrix that never failed (a fourth factorization)."""
    out = tmp_path / "matrix"
    run_on_two_ranks("tests/mpi_slab_matrix.py", FSI, str(out), "mesh.h_min=0.1", "mesh.h_max=0.1",
                     "mover.name=linear", "mover.linear.increments=2")
    records = [json.loads(Path(f"{out}.rank{r}.json").read_text()) for r in range(2)]
    assert records[0] == records[1]
    steps = records[0]
    assert steps["broken"]["message"].startswith("solve across the ranks failed (KSP reason -11")
    assert max(steps[k]["error"] for k in ("again", "exact", "doubled")) <= 1e-12
    assert [steps[k]["factorizations"] for k in ("again", "exact", "doubled")] == [2, 3, 4]
