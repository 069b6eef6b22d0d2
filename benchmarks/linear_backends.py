"""Analysis, factorization and solve times of every installed backend on the flow Jacobian.

The Jacobian is the beam-in-channel optimization scene's constrained
Navier-Stokes Jacobian at a perturbed state and design (``--elements-x``
elements along the channel). Each backend analyses the pattern once, then
factorizes two matrices of that pattern (the second one is what every Newton
step and design iteration pays), solves and solves with the transpose; the
answers are compared with SuperLU's. Run it under the PETSc environment to
include MUMPS (``docs/parallel.md``).

    python benchmarks/linear_backends.py [--elements-x 180] [--threads 2]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path


SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization.toml"


def jacobians(nx: int):
    import numpy as np
    import tofsi
    from tofsi.linalg import nested_dissection
    h = 2.0 / nx
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}"])
    model = tofsi.Problem(scene).model
    flow = model.flow
    rng = np.random.default_rng(0)
    rho = model.densities()
    out = []
    for k in range(2):
        r = np.clip(rho + 0.2 * k * rng.standard_normal(rho.size), 0, 1)
        w = flow.initial() + 0.1 * k * rng.standard_normal(flow.size) * ~flow.bc.is_fixed
        out.append(flow.jacobian(w, None, r, flow.density)[0])
    perm = nested_dissection(flow.grid(), last=np.arange(flow.size) >= flow.n_velocity)
    return out, perm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements-x", type=int, default=180)
    parser.add_argument("--threads", type=int, default=0, help="solver threads (0: one per core)")
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks"))
    args = parser.parse_args()

    import numpy as np
    from tofsi.linalg import DirectSolver, backends
    from tofsi.runs.output import write_json
    from tofsi.linalg.threads import set_blas_threads, solver_threads

    set_blas_threads(1)
    backends.set_threads(solver_threads(args.threads))
    (A0, A1), perm = jacobians(args.elements_x)
    b = np.random.default_rng(1).standard_normal(A0.shape[0])
    rows, reference = [], None
    for name in ["superlu"] + [n for n in backends.available() if n != "superlu"]:
        backend = backends.get_backend(name)
        backends.clear_cache()
        t0 = time.perf_counter()
        analysis = backends.analysis_for(A0, backend, perm)
        t_analysis = time.perf_counter() - t0
        t_factor = []
        for A in (A0, A1):                       # the first (MUMPS: with its analysis), then a refactorization
            second = None
            t0 = time.perf_counter()
            second = DirectSolver(A, perm=perm, backend=name)
            t_factor.append(time.perf_counter() - t0)
        del analysis
        t2 = time.perf_counter()
        x = second.factorization.solve(b)
        t3 = time.perf_counter()
        x, xt = second.solve(b), second.solve_transpose(b)
        reference = reference or (x, xt)
        err = max(np.linalg.norm(x - reference[0]) / np.linalg.norm(reference[0]),
                  np.linalg.norm(xt - reference[1]) / np.linalg.norm(reference[1]))
        rows.append({"backend": name, "analysis_s": t_analysis, "first_factorization_s": t_factor[0],
                     "factorization_s": t_factor[1],
                     "solve_s": t3 - t2, "factor_nnz": second.factorization.factor_nnz,
                     "memory_gb": second.memory_bytes / 1024**3, "difference_to_superlu": err,
                     "analyses": backend.analyses})
    print(f"flow Jacobian: n = {A0.shape[0]}, nnz = {A0.nnz}; machine {platform.machine()}, "
          f"Python {platform.python_version()}, solver threads {solver_threads(args.threads)}, BLAS threads 1")
    print(f"{'backend':9s} {'analysis':>9s} {'1st fact':>8s} {'refact':>8s} {'solve':>7s} {'nnz(LU)':>11s} "
          f"{'GB':>6s} {'vs SuperLU':>10s}")
    for r in rows:
        print(f"{r['backend']:9s} {r['analysis_s']:9.2f} {r['first_factorization_s']:8.2f} "
              f"{r['factorization_s']:8.2f} {r['solve_s']:7.3f} "
              f"{r['factor_nnz']:11d} {r['memory_gb']:6.2f} {r['difference_to_superlu']:10.1e}")
    write_json(args.output / f"linear_backends_{args.elements_x}.json",
               {"n": A0.shape[0], "nnz": A0.nnz, "rows": rows})


if __name__ == "__main__":
    main()
