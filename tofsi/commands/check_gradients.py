"""``tofsi check-gradients SCENE``: adjoint versus finite differences, block by block and total.

Exit status 1 when any check fails. Every Jacobian block of the continuation
stage ``--stage`` is checked on the solved state of a design (fixed seed)
with a Taylor test (rate 2, or round-off remainders for a linear map) and
central differences; then the objective's and the constraints' total
derivatives with respect to the design variables. The Taylor steps are chosen
from the remainder's size against the measured round-off floor
(:func:`adjoint.checks.taylor_check`); a check whose remainder is at that
floor at every step is reported "inconclusive", not failed.

The stage is by default the scene's first two-way stage where it has one
(so a two-way scene's two-way gradient is what is checked), else 0. The
design is ``--design FILE`` (or ``design.initial``) when given; else, at a
two-way stage after one-way stages, the design those stages reach (run as
``tofsi optimize`` runs them: a soft structure's random gray design is no
state the mesh can follow), slightly perturbed; else a random design in
[0.1, 0.9].
"""

from __future__ import annotations

import dataclasses
import tempfile

import numpy as np

from adjoint.checks import check_blocks, check_totals
from tofsi.commands.context import stage_index
from tofsi.coupling.coupled import continuation, two_way_stages
from tofsi.optimization.optimize import Optimizer
from tofsi.runs.output import write_json
from tofsi.optimization.problem import Problem

PERTURBATION = 0.02      # of a reached design: a generic point, still one the mesh can follow


def taylor_step(beta: float) -> float:
    """The Taylor test's first step along a unit-normal design direction: 1e-2, smaller for a
    sharp projection (its transition is ~1/beta wide; the remainder must be in its O(eps^2)
    range from the first step)."""
    return 1e-2 / max(1.0, beta / 4.0)


CHECK_TOL = 1e-11        # coupled.tol of the checked solves
CHECK_FLOW_TOL = 1e-13   # fluid.newton_tol of the checked solves (the iterative path's flow)
CHECK_ADJOINT_TOL = 1e-10    # solver.adjoint_tol of the checked gradients (the iterative path)


def checked_scene(scene):
    """The scene with its solves tightened so the central differences see the discrete
    gradient: they divide the difference of two solves by a step of 1e-5.

    * ``coupled.tol`` to ``CHECK_TOL``: 1e-9 (the default) leaves up to about 1e-4 of noise in
      them where the motion is large (measured on the large-deformation scene: 1.4e-4 at 1e-9,
      2.3e-6 at 1e-11);
    * ``fluid.newton_tol`` to ``CHECK_FLOW_TOL``: an LU's last Newton step lands far below the
      tolerance, but the iterative path's inexact steps stop just under it, and at 1e-10 the
      objective of the beam scene moved by about 1e-9 relative between nearby designs, so the
      differences were 1e-4 off (a FAILED check of a right gradient; 210 elements, 2026-11-27);
    * ``solver.adjoint_tol`` to ``CHECK_ADJOINT_TOL``: the iterative path's gradient is 3e-6 to
      2.5e-5 off the LU's at the default 3e-6, what optimization needs but not what a check of
      the derivatives at 1e-5 can pass.
    The direct path's results hardly change (its Newton stops at round-off either way)."""
    tables = {}
    if scene.coupled.tol > CHECK_TOL:
        tables["coupled"] = dataclasses.replace(scene.coupled, tol=CHECK_TOL)
    if "fluid" in scene.tables and scene.fluid.newton_tol > CHECK_FLOW_TOL:
        tables["fluid"] = dataclasses.replace(scene.fluid, newton_tol=CHECK_FLOW_TOL)
    if scene.solver.adjoint_tol > CHECK_ADJOINT_TOL:
        tables["solver"] = dataclasses.replace(scene.solver, adjoint_tol=CHECK_ADJOINT_TOL)
    return scene.with_tables(**tables) if tables else scene


def uniform(initial: str) -> bool:
    """Whether ``design.initial`` is a number (a uniform start: a poor point to check, where
    a density near 0 or 1 leaves the Taylor remainders at round-off) rather than a file."""
    try:
        float(initial)
    except ValueError:
        return False
    return True


def checked_stage(scene, text) -> int:
    """``--stage``: as given, or the first two-way stage, or 0."""
    if text is not None:
        return stage_index(scene, text)
    stages = two_way_stages(scene)
    return stages[0] if stages else 0


def run(scene, args, ctx) -> dict:
    scene = checked_scene(scene)
    problem = Problem(scene)
    rng = np.random.default_rng(args.seed)
    stage = checked_stage(scene, getattr(args, "stage", None))
    record = continuation(scene, stage)
    if scene.design.initial and not uniform(scene.design.initial):      # the user's design file
        gamma, design = problem.initial_design(), scene.design.initial
    elif stage > 0 and stage in two_way_stages(scene):
        with ctx.step(f"reaching stage {stage} through the scene's stages 0 to {stage - 1}"), \
                tempfile.TemporaryDirectory() as scratch:
            reached = Optimizer(problem, scratch).design_after(stage)
        gamma = np.clip(reached + PERTURBATION * rng.uniform(-1, 1, reached.size), 0.0, 1.0)
        design = f"reached by stages 0-{stage - 1}, perturbed by {PERTURBATION:g}"
    else:
        gamma, design = rng.uniform(0.1, 0.9, problem.n_design), "random in [0.1, 0.9]"
    problem.set_stage(record)
    coupling = record.coupling or scene.effects.coupling
    ctx.say(f"{scene.name}: {problem.n_design} design variables; {problem.model.mesh.n_elements} elements; "
            f"stage {stage} ({coupling}, beta {record.params.beta:g}); design {design}; seed {args.seed}; "
            f"coupled solves to {scene.coupled.tol:g}")
    with ctx.step("solving the design"):
        state = problem.solve(gamma)
    with ctx.step("checking every Jacobian block and the total derivatives"):
        rows = (check_blocks(problem.model.system_for(state.stage), state, args.seed)
                + check_totals(problem, gamma, args.seed, eps0=taylor_step(record.params.beta)))
    ctx.say(f"{'check':28s} {'Taylor rate':>11s} {'steps':>17s} {'round-off':>9s} {'CD rel. error':>13s}  result")
    for r in rows:
        rate = "linear" if r["linear"] else "-" if r["min_rate"] != r["min_rate"] else f"{r['min_rate']:.3f}"
        steps = f"{min(r['eps']):.1e}-{max(r['eps']):.1e}"
        ctx.say(f"{r['check']:28s} {rate:>11s} {steps:>17s} {r['round_off_floor']:9.1e} {r['cd_error']:13.2e}  "
                f"{'ok' if r['linear'] else r['result']}")
    passed = all(r["passed"] for r in rows)
    inconclusive = [r["check"] for r in rows if r["result"] == "inconclusive"]
    if inconclusive:
        ctx.say(f"inconclusive: {', '.join(inconclusive)} (the remainder is at the round-off floor at every "
                "step; no failure: a wrong gradient leaves a first-order remainder above it)")
    ctx.begin()
    write_json(ctx.path("check_gradients.json"), {"passed": passed, "stage": stage, "coupling": coupling,
                                                 "design": design, "inconclusive": inconclusive, "checks": rows})
    ctx.exit_status = 0 if passed else 1
    return {"scene": scene.name, "passed": passed, "stage": stage, "coupling": coupling, "design": design,
            "inconclusive": inconclusive, "checks": rows, "outputs": list(ctx.written)}
