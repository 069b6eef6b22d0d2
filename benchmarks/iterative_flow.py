"""Robustness of the iterative flow solve: FGMRES iterations against mesh size, alpha_max, Reynolds number
and the design's sharpness, its memory per element, and its time against the sparse LU.

The system is the beam-in-channel scene's constrained Navier-Stokes Jacobian
at a converged flow (solved with the LU) for a design made from a smooth
random field (filter radius 0.1 m) projected with sharpness ``beta``
(``beta`` 1: gray, 64: nearly 0/1, as along an optimization's continuation),
the fixed wall solid. The right-hand side is the Newton residual of the
converged state perturbed by 1 %, so both solves answer the same question;
``err v`` / ``err p`` are the iterative solution's velocity / pressure
errors relative to the LU's. ``setup`` is building the preconditioner (two
AMG hierarchies) or factorizing; ``solve`` one forward solve to a scaled
relative residual of ``--tol``; ``adj`` one transposed solve (for the
iterative path including the hierarchy of ``A^T``). ``kB/el`` is the
solver's own memory per element: the LU's factors, or the preconditioner's
blocks and hierarchies plus the 50-vector FGMRES basis.

    python -m benchmarks.iterative_flow [--sizes 40 80 160 320] [--quick]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization.toml"


def design(mesh, beta: float, seed: int = 0):
    """A projected smooth random design (E,) in the design region, the fixed wall solid."""
    import numpy as np
    from tofsi.mesh.structured import DESIGN, SOLID
    c = mesh.centroids
    rng = np.random.default_rng(seed)
    k = rng.normal(size=(12, 2)) * 6.0
    phase = rng.uniform(0, 2 * np.pi, 12)
    field = np.cos(c @ k.T + phase).sum(axis=1) / np.sqrt(6.0)                 # (E,) smooth, O(1)
    rho = 1.0 / (1.0 + np.exp(-beta * field)) * 0.6
    return np.where(mesh.region == SOLID, 1.0, np.where(mesh.region == DESIGN, rho, 0.0))


def case(nx: int, alpha_max: float, density: float, beta: float, tol: float, pressure_solver: str):
    import numpy as np
    import tofsi
    from tofsi.physics.flow_preconditioner import flow_preconditioner
    h = 2.0 / nx
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}", f"fluid.alpha_max={alpha_max}",
                                     f"fluid.density={density}"])
    model = tofsi.Problem(scene).model
    flow = model.flow
    rho = design(flow.mesh, beta)
    w, _ = flow.solve(None, rho)
    J = flow.jacobian(w, None, rho)[0]
    rng = np.random.default_rng(1)
    b = -flow.bc.homogenize(flow.residual(w + 0.01 * rng.standard_normal(w.size) * ~flow.bc.is_fixed, None, rho))
    row = {"nx": nx, "elements": flow.mesh.n_elements, "unknowns": flow.size, "alpha_max": alpha_max,
           "Re": density, "beta": beta, "solid fraction": float(np.mean(rho > 0.5))}
    t0 = time.perf_counter()
    lu = flow.factorize(J)
    t1 = time.perf_counter()
    x_lu = lu.solve(b)
    t2 = time.perf_counter()
    xt_lu = lu.solve_transpose(b)
    row.update(lu_setup=t1 - t0, lu_solve=t2 - t1, lu_kb=lu.memory_bytes / flow.mesh.n_elements / 1e3)
    del lu
    t0 = time.perf_counter()
    P = flow_preconditioner(flow, J, None, rho, pressure_solver=pressure_solver, tol=tol)
    P.max_iter = 500
    t1 = time.perf_counter()
    try:
        x = P.solve(b)
        t2 = time.perf_counter()
        its = P.iterations
        xt = P.solve_transpose(b)
        t3 = time.perf_counter()
        nv = flow.n_velocity
        row.update(it_setup=t1 - t0, it_solve=t2 - t1, it_adj=t3 - t2, iterations=its,
                   iterations_T=P.iterations,
                   err_v=float(np.linalg.norm((x - x_lu)[:nv]) / np.linalg.norm(x_lu[:nv])),
                   err_p=float(np.linalg.norm((x - x_lu)[nv:]) / np.linalg.norm(x_lu[nv:])),
                   err_T=float(np.linalg.norm(xt - xt_lu) / np.linalg.norm(xt_lu)))
    except Exception as err:                                   # noqa: BLE001 - where it breaks is a result
        row.update(it_setup=t1 - t0, iterations=-1, failure=str(err)[:80])
    row["it_kb"] = (P.memory_bytes + 50 * 8 * flow.size) / flow.mesh.n_elements / 1e3
    return row


def schur_study(nx: int, alpha_max: float, density: float, beta: float, tol: float):
    """FGMRES iterations with four Schur complement approximations (the velocity block by AMG):
    the pressure mass over mu, the mass weighted per element by 1/(mu + alpha h^2), SIMPLE's
    B diag(A)^-1 B^T, and the Cahouet-Chabard sum M_mu^-1 + L_alpha^-1 (the one shipped)."""
    import numpy as np
    import tofsi
    from tofsi.linalg.iterative import BlockSaddlePreconditioner
    from tofsi.physics.flow_preconditioner import element_areas, schur_parts
    h = 2.0 / nx
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}", f"fluid.alpha_max={alpha_max}",
                                     f"fluid.density={density}"])
    flow = tofsi.Problem(scene).model.flow
    rho = design(flow.mesh, beta)
    w, _ = flow.solve(None, rho)
    J = flow.jacobian(w, None, rho)[0]
    rng = np.random.default_rng(1)
    b = -flow.bc.homogenize(flow.residual(w + 0.01 * rng.standard_normal(w.size) * ~flow.bc.is_fixed, None, rho))
    mass, darcy = schur_parts(flow, None, rho)
    area = element_areas(flow.corners())
    mu = flow.settings.viscosity
    weighted = np.bincount(flow.mesh.quads.ravel(), np.repeat(area / (4 * (mu + flow.alpha(rho) * area)), 4),
                           minlength=mass.size)
    nv = flow.n_velocity
    diagonal = np.abs(J.diagonal()[:nv])
    simple = np.where(flow.bc.is_fixed[:nv], 0.0, 1.0 / diagonal)
    variants = {"mass/mu": (mass, None), "mass/(mu+alpha h^2)": (weighted, None),
                "SIMPLE": (np.full(mass.size, np.inf), simple), "Cahouet-Chabard": (mass, darcy)}
    out = {}
    for name, (m, d) in variants.items():
        P = BlockSaddlePreconditioner(J, nv, m, d, flow.bc.is_fixed, tol=tol, max_iter=500)
        try:
            P.solve(b)
            out[name] = P.iterations
        except Exception:                                       # noqa: BLE001 - a failure is a result
            out[name] = -1
    return out


def show(row) -> str:
    if row.get("iterations", -1) < 0:
        return (f"{row['elements']:8d} {row['alpha_max']:8.0e} {row['Re']:6.0f} {row['beta']:5.0f}   "
                f"FAILED ({row.get('failure', '')})")
    return (f"{row['elements']:8d} {row['alpha_max']:8.0e} {row['Re']:6.0f} {row['beta']:5.0f} "
            f"{row['iterations']:5d} {row['iterations_T']:5d} {row['err_v']:8.1e} {row['err_p']:8.1e} "
            f"{row['it_setup']:6.2f} {row['it_solve']:6.2f} {row['it_adj']:6.2f} {row['lu_setup']:6.2f} "
            f"{row['lu_solve']:6.3f} {row['it_kb']:6.1f} {row['lu_kb']:6.1f}")


HEADER = ("elements    alpha     Re  beta   its  itsT    err v    err p  setup  solve    adj "
          "LUfact LUsolv  kB/el LUkB/el")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[40, 80, 160, 320])
    parser.add_argument("--alphas", type=float, nargs="+", default=[1e3, 1e5, 1e7, 1e9])
    parser.add_argument("--reynolds", type=float, nargs="+", default=[0.0, 1.0, 10.0, 50.0])
    parser.add_argument("--betas", type=float, nargs="+", default=[1.0, 4.0, 16.0, 64.0])
    parser.add_argument("--tol", type=float, default=1e-10)
    parser.add_argument("--pressure-solver", default="amg", choices=["amg", "direct"])
    parser.add_argument("--studies", nargs="+", default=["schur", "size", "alpha", "reynolds", "design"])
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks"))
    args = parser.parse_args()
    from tofsi.linalg.threads import set_blas_threads
    set_blas_threads(1)
    base = dict(nx=80, alpha_max=1e5, density=1.0, beta=4.0)
    plans = {"size": [dict(base, nx=n) for n in args.sizes],
             "alpha": [dict(base, alpha_max=a) for a in args.alphas],
             "reynolds": [dict(base, density=r) for r in args.reynolds],
             "design": [dict(base, beta=b) for b in args.betas]}
    rows = []
    if "schur" in args.studies:
        print("\nschur: FGMRES iterations (-1: not converged in 500) at 80 x 40, Re 1")
        print(f"{'alpha_max':>9} {'beta':>5}  mass/mu  mass/(mu+alpha h^2)  SIMPLE  Cahouet-Chabard")
        for alpha_max in (1e3, 1e5, 1e7):
            for beta in (1.0, 64.0):
                its = schur_study(80, alpha_max, 1.0, beta, args.tol)
                rows.append({"study": "schur", "alpha_max": alpha_max, "beta": beta, **its})
                print(f"{alpha_max:9.0e} {beta:5.0f}  " + "  ".join(f"{v:>{len(k)}d}" for k, v in its.items()),
                      flush=True)
    for study in [s for s in args.studies if s != "schur"]:
        print(f"\n{study}\n{HEADER}", flush=True)
        for kw in plans[study]:
            row = case(tol=args.tol, pressure_solver=args.pressure_solver, **kw)
            row["study"] = study
            rows.append(row)
            print(show(row), flush=True)
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "iterative_flow.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
