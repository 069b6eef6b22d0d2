"""``tofsi check-gradients SCENE``: adjoint versus finite differences, block by block and total.

Exit status 1 when any check fails. Every Jacobian block the scene has is
checked on the solved state of a random design (fixed seed) with a Taylor
test (rate 2, or round-off remainders for a linear map) and central
differences; then the objective's and the volume constraint's total
derivatives with respect to the design variables.
"""

from __future__ import annotations

import numpy as np

from adjoint.checks import check_blocks, check_totals
from tofsi.output import write_json
from tofsi.problem import Problem


def run(scene, args, ctx) -> dict:
    problem = Problem(scene)
    rng = np.random.default_rng(args.seed)
    gamma = rng.uniform(0.1, 0.9, problem.n_design)
    ctx.say(f"{scene.name}: {problem.n_design} design variables; "
            f"{problem.model.mesh.n_elements} elements; seed {args.seed}")
    with ctx.step("solving the random design"):
        state = problem.solve(gamma)
    with ctx.step("checking every Jacobian block and the total derivatives"):
        rows = check_blocks(problem.model.system_for(state.params), state, args.seed) + check_totals(problem, gamma, args.seed)
    ctx.say(f"{'check':28s} {'Taylor rate':>11s} {'CD rel. error':>14s}  result")
    for r in rows:
        rate = "linear" if r["linear"] else f"{r['min_rate']:.3f}"
        ctx.say(f"{r['check']:28s} {rate:>11s} {r['cd_error']:14.2e}  {'ok' if r['passed'] else 'FAILED'}")
    passed = all(r["passed"] for r in rows)
    ctx.begin()
    write_json(ctx.path("check_gradients.json"), {"passed": passed, "checks": rows})
    ctx.exit_status = 0 if passed else 1
    return {"scene": scene.name, "passed": passed, "checks": rows, "outputs": list(ctx.written)}
