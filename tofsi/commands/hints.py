"""What to try after a numerical failure: one sentence the command line adds to the error."""

from __future__ import annotations

import movers


def hint(err, scene, command: str = "") -> str:
    """A hint for the :class:`~tofsi.core.errors.NumericalError` ``err`` of a ``tofsi command``
    run of ``scene`` (empty when there is nothing specific to say)."""
    message, diagnostic = str(err), err.diagnostic
    if scene is None:
        return ""
    if scene.mover.name != "none" and message.startswith(f"{scene.mover.name} mover") and "invert" in message:
        advice = movers.mover_class(scene.mover.name)(scene.mover.options).inversion_hint
        if advice:
            return advice
    if (message.startswith("flow solve") and "density" in diagnostic
            and scene.effects.fluid == "navier-stokes" and scene.fluid.density > 0):
        failed_at, full, steps = diagnostic["density"], scene.fluid.density, scene.fluid.continuation_steps
        if failed_at == 0.0:
            where = "the Reynolds continuation failed at its start, Stokes flow (fluid density 0)"
        else:
            where = (f"the Reynolds continuation stopped at fluid density {failed_at:.4g} of {full:.4g}, "
                     f"after converging at {max(failed_at - full / steps, 0.0):.4g}")
        return (f"{where}; try more steps (--set fluid.continuation_steps={2 * steps}), more Newton "
                f"iterations (fluid.newton_max_iter = {scene.fluid.newton_max_iter}), a finer mesh, or a "
                "smaller fluid.density or inlet velocity")
    on_the_start = command == "solve" or (command == "optimize" and diagnostic.get("iteration") == 0)
    if (on_the_start and scene.has_design and scene.effects.coupling == "two-way"
            and not scene.design.initial and "mover" in message):
        return ("the two-way coupled solve failed on the uniform gray design (too soft for the "
                "flow's load); start the schedule one-way (design.coupling = [\"one-way\", ..., "
                "\"two-way\"]) or from a saved design: --set design.initial=FILE")
    if command == "solve" and scene.has_design and message.startswith("structure: displacement"):
        return ("the structure is held, but this design is far too soft for the flow's load "
                "(a gray starting design of a soft scene); solve a designed structure: "
                "--design FILE (the design.npy of tofsi optimize), with --stage last")
    return ""
