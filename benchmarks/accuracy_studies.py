"""The studies of ``benchmarks/accuracy_vs_time.py``: each setting's result, error against a
reference solution and wall time, as rows (the script writes them and reports them)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "examples" / "scenes"


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


# ---- movers ---------------------------------------------------------------------------
MOVER_PROBLEMS = {"foil rotation": ("foil_in_channel", ["deformation.mode=rotation"]),
                  "beam": ("beam_in_channel", [])}
# Two stiffened layers, the best factors of docs/mesh_motion_study.md (graded mesh): the
# setting a user would run (the unstiffened linear mover inverts elements here).
LAYERS = {("foil rotation", "spring"): [2.1, 1.3], ("foil rotation", "linear"): [5.0, 2.0],
          ("foil rotation", "yeoh"): [5.2, 2.1], ("beam", "spring"): [3.5, 3.2],
          ("beam", "linear"): [3.6, 1.5], ("beam", "yeoh"): [3.6, 1.4]}
MOVER_SETTINGS = {
    "spring": ("increments", [3, 5, 10, 20, 30, 60], 240, 30),
    "linear": ("increments", [1, 2, 5, 10, 20], 80, 1),
    "yeoh": ("newton_tol", [1e-3, 1e-4, 1e-6, 1e-8, 1e-10], 1e-13, 1e-10),
}


def move(problem, mover, extra):
    import tofsi
    from tofsi.core.errors import NumericalError
    from tofsi.coupling.motion import motion_setup, run_move
    scene_name, base = MOVER_PROBLEMS[problem]
    layers = ",".join(map(str, LAYERS[problem, mover]))
    scene = tofsi.load_scene(SCENES / f"{scene_name}.toml",
                             base + [f"mover.name={mover}", f"mover.layers=[{layers}]"] + extra)
    setup = motion_setup(scene)
    t0 = time.perf_counter()
    try:
        _, result = run_move(scene, setup=setup)
        x, q = result.displacement, result.report.quality[-1]
    except NumericalError as err:
        x, q = err.state, err.diagnostic["quality"]
    return x, q["min_skewness"], time.perf_counter() - t0, setup.mesh.n_nodes


def mover_study(quick: bool) -> list[dict]:
    rows = []
    for problem in MOVER_PROBLEMS:
        for mover, (key, values, ref_value, default) in MOVER_SETTINGS.items():
            values = sorted(set(values[:2]) | {default}) if quick else values   # the report needs the default
            x_ref, skew_ref, t_ref, _ = move(problem, mover, [f"mover.{mover}.{key}={ref_value}"])
            for v in values:
                x, skew, t, n = move(problem, mover, [f"mover.{mover}.{key}={v}"])
                rows.append({"study": "parameter", "problem": problem, "mover": mover, "parameter": key,
                             "value": v, "time_s": t, "min_skewness": skew, "nodes": n,
                             "error": float(np.abs(x - x_ref).max() / np.abs(x_ref).max()),
                             "default": v == default, "reference_time_s": t_ref})
            for solver in ("direct", "amg"):
                x, skew, t, n = move(problem, mover, [f"mover.{mover}.tangent_solver={solver}"])
                rows.append({"study": "solver", "problem": problem, "mover": mover, "parameter": "tangent_solver",
                             "value": solver, "time_s": t, "min_skewness": skew, "nodes": n,
                             "error": float(np.abs(x - x_ref).max() / np.abs(x_ref).max()),
                             "default": solver == "direct"})
            refine = [1.0, 1.5] if quick else [0.75, 1.0, 1.5, 2.0]
            for r in refine:
                x, skew, t, n = move(problem, mover, [f"mesh.h_min={0.0125 / r}", f"mesh.h_max={0.05 / r}"])
                rows.append({"study": "mesh", "problem": problem, "mover": mover, "parameter": "refinement",
                             "value": r, "time_s": t, "min_skewness": skew, "nodes": n, "error": np.nan,
                             "default": r == 1.0})
    return rows


# ---- flow -----------------------------------------------------------------------------
FLOW_REFERENCE_H = 0.00625
def flow_study(quick: bool) -> list[dict]:
    import dataclasses

    import tofsi
    from tofsi.mesh.channel import build_mesh
    from tofsi.mesh.structured import SOLID
    from tofsi.physics.flow import Flow
    from tofsi.physics.structure import Structure
    scene = tofsi.load_scene(SCENES / "beam_in_channel.toml")
    hs = [0.025, 0.0125, FLOW_REFERENCE_H] if quick else [0.05, 0.035, 0.025, 0.0175, 0.0125, FLOW_REFERENCE_H]
    rows = []
    for model in ("stokes", "navier-stokes"):
        results = []
        for h in hs:
            s = scene.with_tables(mesh=dataclasses.replace(scene.mesh, h_min=h, h_max=4 * h))
            mesh = build_mesh(s.geometry, s.mesh)
            rho = (mesh.region == SOLID).astype(float)
            flow = Flow(mesh, dataclasses.replace(s.fluid, alpha_max=1e6), stokes=model == "stokes")
            (w, _), t = timed(flow.solve, None, rho)
            drag = Structure(mesh, s.structure, flow).figures(np.zeros(2 * mesh.n_nodes), w, None, rho)["drag"]
            results.append((h, mesh.n_elements, t, drag, flow.figures(w, rho=rho)["pressure_drop"]))
        _, _, _, drag_ref, dp_ref = results[-1]
        for h, n, t, drag, dp in results[:-1]:
            rows.append({"study": "flow", "model": model, "h_min": h, "elements": n, "time_s": t,
                         "drag": drag, "pressure_drop": dp, "drag_error": abs(drag / drag_ref - 1),
                         "pressure_drop_error": abs(dp / dp_ref - 1), "default": h == 0.0125})
    return rows


# ---- coupling -------------------------------------------------------------------------
def coupling_study(quick: bool) -> list[dict]:
    import tofsi
    from tofsi.coupling.coupled import CoupledModel
    base = ["mesh.h_min=0.05", "mesh.h_max=0.05", "effects.coupling=two-way", "mover.name=yeoh",
            "structure.youngs_modulus=5e5", "fluid.alpha_max=1e4"]

    def solve(method, tol):
        scene = tofsi.load_scene(SCENES / "beam_in_channel_optimization.toml",
                                 base + [f"coupled.method={method}", f"coupled.tol={tol}"])
        model = CoupledModel(scene)
        c = model.mesh.centroids[model.design_elements]
        rho = model.densities(((np.abs(c[:, 0] - 1.0) < 0.1) & (c[:, 1] < 0.6)).astype(float))
        state, t = timed(model.solve, rho)
        return state, t
    ref, _ = solve("monolithic", 1e-12)
    rows = []
    for method in ("partitioned", "monolithic"):
        for tol in ([1e-4, 1e-9] if quick else [1e-3, 1e-4, 1e-6, 1e-9, 1e-11]):
            state, t = solve(method, tol)
            rows.append({"study": "coupling", "method": method, "tol": tol, "time_s": t,
                         "error": float(np.abs(state.u - ref.u).max() / np.abs(ref.u).max()),
                         "default": method == "partitioned" and tol == 1e-9})
    return rows


# ---- gradient -------------------------------------------------------------------------
def gradient_study(quick: bool) -> list[dict]:
    import tofsi
    scene = tofsi.load_scene(SCENES / "beam_in_channel_optimization.toml",
                             ["mesh.h_min=0.05", "mesh.h_max=0.05", "fluid.newton_tol=1e-13"])
    P = tofsi.Problem(scene)
    rng = np.random.default_rng(0)
    gamma = rng.uniform(0.1, 0.9, P.n_design)
    P.solve(gamma)
    (f0, df), t_adj = timed(P.evaluate, gamma)
    _, t_fwd = timed(P.solve, gamma + 1e-3)
    sample = rng.choice(P.n_design, 4 if quick else 12, replace=False)
    rows = [{"study": "gradient", "method": "adjoint", "h": np.nan, "error": np.nan,
             "time_per_gradient_s": t_adj, "default": True}]
    for h in (1e-2, 1e-4, 1e-6, 1e-8):
        errs, t_total = [], 0.0
        for i in sample:
            e = np.zeros(P.n_design)
            e[i] = h
            (fp, _), t = timed(P.evaluate, gamma + e)
            t_total += t
            errs.append(abs((fp - f0) / h - df[i]) / max(abs(df).max(), 1e-300))
        rows.append({"study": "gradient", "method": "forward differences", "h": h, "error": float(np.max(errs)),
                     "time_per_gradient_s": t_total / len(sample) * P.n_design, "default": False})
    for r in rows:
        r["forward_solve_s"] = t_fwd
        r["design_variables"] = P.n_design
    return rows


# ---- elements -------------------------------------------------------------------------
# (problem, scene, overrides, the fixed design's fluid indicator or None, quantity, meshes, reference mesh)
ELEMENT_PROBLEMS = {
    "double pipe": ("topflow_double_pipe", ["effects.fluid=stokes"], "pipes", "dissipation-strain",
                    [24, 48, 96, 192], 240),
    "pipe bend": ("topflow_pipe_bend", ["effects.fluid=stokes"], "annulus", "dissipation-strain",
                  [20, 40, 80, 160], 240),
    "foil drag": ("foil_in_channel", ["effects.fluid=stokes", "effects.structure=none", "fluid.alpha_max=1e8"],
                  None, "drag", [0.05, 0.025, 0.0125, 0.00625], 0.003125),
}
ELEMENT_DEFAULT = {"double pipe": 96, "pipe bend": 80, "foil drag": 0.0125}


def element_case(problem: str, element: str, size) -> dict:
    """One forward solve of ``problem`` with ``element`` on mesh ``size`` (elements per unit
    length, or the foil's h_min): its quantity, solve time and element count."""
    import tofsi
    from tofsi.coupling.coupled import CoupledModel
    from tofsi.objectives.dissipation_strain import StrainDissipation
    scene_name, overrides, design, quantity, _, _ = ELEMENT_PROBLEMS[problem]
    mesh = ([f"mesh.h_min={size}", f"mesh.h_max={4 * size}"] if design is None
            else [f"mesh.h_min={1 / size}", f"mesh.h_max={1 / size}"])
    scene = tofsi.load_scene(SCENES / f"{scene_name}.toml", overrides + mesh + [f"fluid.element={element}"])
    model = CoupledModel(scene)
    if design is None:
        rho = model.densities()
    else:                                              # rho on the design region from the geometry
        c = model.mesh.centroids
        if design == "pipes":
            fluid = (np.abs(c[:, 1] - 0.25) < 1 / 12) | (np.abs(c[:, 1] - 0.75) < 1 / 12)
        else:
            r = np.hypot(c[:, 0], c[:, 1])
            fluid = (r > 0.7) & (r < 0.9)
        rho = np.where(fluid, 0.0, 1.0)
    state, t = timed(model.solve, rho)
    value = (StrainDissipation().value(model, state) if quantity == "dissipation-strain"
             else model.figures(state)["drag"])
    return {"value": value, "time_s": t, "elements": model.mesh.n_elements}


def element_study(quick: bool) -> list[dict]:
    """Each case in a fresh process (its peak memory, VmHWM, is the run's)."""
    import json
    import subprocess
    import sys
    rows = []
    for problem, (_, _, _, _, sizes, reference) in ELEMENT_PROBLEMS.items():
        sizes = sizes[:2] if quick else sizes
        cases = [(e, s) for s in sizes for e in ("q2q1", "q1q1")] + [("q2q1", reference)]
        results = {}
        for element, size in cases:
            code = ("import json, benchmarks.accuracy_vs_time as b; "
                    f"r = b.element_case({problem!r}, {element!r}, {size!r}); "
                    "r['peak_mb'] = [int(l.split()[1]) / 1024 for l in open('/proc/self/status') "
                    "if l.startswith('VmHWM')][0]; print(json.dumps(r))")
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
            results[element, size] = json.loads(out.stdout.strip().splitlines()[-1])
        ref = results["q2q1", reference]["value"]
        for element, size in cases[:-1]:
            r = results[element, size]
            rows.append({"study": "elements", "problem": problem, "element": element, "size": size,
                         "elements": r["elements"], "value": r["value"], "reference": ref,
                         "error": abs(r["value"] / ref - 1), "time_s": r["time_s"], "peak_mb": r["peak_mb"],
                         "default": element == "q2q1" and size == ELEMENT_DEFAULT[problem]})
    return rows


STUDIES = {"movers": mover_study, "flow": flow_study, "coupling": coupling_study, "gradient": gradient_study,
           "elements": element_study}
