"""Nearly void elements at finite strain: the energy interpolation against plain SIMP.

The headline scene (``beam_in_channel_optimization_fsi``, 80 x 40 elements) solved
one-way at a designed structure -- a solid post around the wall (16 % of the design
region, rho ~ 1e-6 elsewhere after the beta = 16 projection) -- under the flow's
load, with the structure softened step by step (E0 = 5, 2.5, 1.25 kPa: the same
as doubling the load; void Emin = 1e-4 E0 as in the scene, and 1e-9 E0, the
``[structure]`` default), ``structure.model = "neo-hookean"`` with

* ``structure.interpolation = "energy"`` -- Wang, Lazarov, Sigmund & Jensen 2014: the
  void's strain energy is the linear one, blended into the neo-Hookean one by g(rho);
* ``structure.interpolation = "simp"`` -- every element neo-Hookean, the void at Emin.

For each: whether the Newton solve converged (else the load factor it reached), its
Newton iterations, load steps and cutbacks, the largest displacement, the smallest
det(I + grad u) over the void elements (their distortion; the void's displacement is
not the fluid mesh's -- the mover carries the fluid nodes) and over the solid, and the
time. Writes ``void_interpolation.md`` and ``.json`` to ``--output``; about two minutes:

    python examples/compare_void_interpolation.py [--output results/compare_void_interpolation]

``TOFSI_EXAMPLE_SMALL=1`` uses a 40 x 20 mesh (the test suite does this).
"""

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

import tofsi
from tofsi.core.errors import NumericalError
from tofsi.physics.structure import Structure

SCENE = Path(__file__).resolve().parent / "scenes" / "beam_in_channel_optimization_fsi.toml"
ONE_WAY = ["effects.coupling=one-way", "effects.mesh_motion=none", 'design.coupling=["one-way"]']
SMALL = os.environ.get("TOFSI_EXAMPLE_SMALL") == "1"
MODULI = (5e3, 2.5e3, 1.25e3)


def post_flow(overrides):
    """The flow state at the post design (solid post x in [0.8, 1.2], y < 0.6; beta 16)."""
    problem = tofsi.Problem(tofsi.load_scene(SCENE, ONE_WAY + overrides))
    c = problem.model.mesh.centroids[problem.model.design_elements]
    post = (np.abs(c[:, 0] - 1.0) < 0.2) & (c[:, 1] < 0.6)
    problem.set_stage(dataclasses.replace(problem.params, beta=16.0))
    return problem, problem.solve(np.where(post, 0.95, 0.05))


def smallest_det(mesh, structure, u, elements) -> float:
    """min det(I + grad u) over the Gauss points of ``elements``."""
    F = structure.finite().kernel.deformation_gradient(u[structure.dofs])[elements]
    return float((F[..., 0, 0] * F[..., 1, 1] - F[..., 0, 1] * F[..., 1, 0]).min())


def one(problem, state, youngs_modulus: float, e_min_ratio: float, interpolation: str) -> dict:
    model = problem.model
    settings = dataclasses.replace(model.scene.structure, youngs_modulus=youngs_modulus, e_min_ratio=e_min_ratio,
                                   model="neo-hookean", interpolation=interpolation)
    st = Structure(model.mesh, settings, model.flow, linear_algebra=model.linear_algebra)
    void, solid = np.flatnonzero(state.rho < 0.01), np.flatnonzero(state.rho > 0.5)
    row = {"E0": youngs_modulus, "e_min_ratio": e_min_ratio, "interpolation": interpolation}
    t0 = time.perf_counter()
    with model.linear_algebra.blas():
        try:
            sol = st.newton_solve(state.w, None, state.rho, state.params)
        except NumericalError as err:
            d = err.diagnostic
            return {**row, "converged": False, "load_factor": d["load_factor"],
                    "newton_iterations": d["newton_iterations"], "cutbacks": d["cutbacks"],
                    "worst": f"det F {d['min_det_F']:.2g} at ({d['centroid'][0]:.2f}, {d['centroid'][1]:.2f})",
                    "time_s": time.perf_counter() - t0}
    u = sol.u
    r = sol.report
    return {**row, "converged": True, "load_factor": 1.0, "newton_iterations": r.newton_iterations,
            "load_steps": r.load_steps, "cutbacks": r.cutbacks,
            "max_displacement": float(np.linalg.norm(u.reshape(-1, 2), axis=1).max()),
            "min_det_void": smallest_det(model.mesh, st, u, void),
            "min_det_solid": smallest_det(model.mesh, st, u, solid), "time_s": time.perf_counter() - t0}


def table(rows) -> str:
    lines = ["| E0 [Pa] | Emin / E0 | void elements | converged | Newton iterations | load steps / cutbacks | "
             "largest displacement [m] | min det(I + grad u), void | min det, solid | time [s] |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        case = f"| {r['E0']:.4g} | {r['e_min_ratio']:.0e} | {r['interpolation']} |"
        if r["converged"]:
            lines.append(f"{case} yes | {r['newton_iterations']} | {r['load_steps']} / {r['cutbacks']} | "
                         f"{r['max_displacement']:.3f} | {r['min_det_void']:.3f} | {r['min_det_solid']:.3f} | "
                         f"{r['time_s']:.2f} |")
        else:
            lines.append(f"{case} no: load factor {r['load_factor']:.3f} ({r['worst']}) | "
                         f"{r['newton_iterations']} | - / {r['cutbacks']} | - | - | - | {r['time_s']:.2f} |")
    return "\n".join(lines) + "\n"


def main(output: Path) -> list[dict]:
    overrides = ["mesh.h_min=0.05", "mesh.h_max=0.05"] if SMALL else []
    problem, state = post_flow(overrides)
    print(f"{problem.model.mesh.n_elements} elements; post design, beta 16")
    cases = [(E, 1e-4) for E in MODULI] + [(E, 1e-9) for E in MODULI[:2]]
    rows = [one(problem, state, E, e_min, interp) for E, e_min in (cases[:2] if SMALL else cases)
            for interp in ("energy", "simp")]
    text = table(rows)
    output.mkdir(parents=True, exist_ok=True)
    (output / "void_interpolation.md").write_text(text)
    (output / "void_interpolation.json").write_text(json.dumps(rows, indent=2))
    print(text)
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("results/compare_void_interpolation"))
    main(parser.parse_args().output)
