"""What to try after a numerical failure: one sentence the command line adds to the error."""

from __future__ import annotations


def hint(err, scene) -> str:
    """A hint for the :class:`~tofsi.errors.NumericalError` ``err`` of a run of ``scene``
    (empty when there is nothing specific to say)."""
    message, diagnostic = str(err), err.diagnostic
    if scene is None:
        return ""
    if message.startswith("spring mover") and "invert" in message:
        n = scene.mover.options.increments
        return (f"the spring analogy inverted elements with mover.spring.increments = {n}; "
                f"try more increments (e.g. --set mover.spring.increments={max(2 * n, 10)})")
    if (message.startswith("flow solve") and "density" in diagnostic
            and scene.effects.fluid == "navier-stokes" and scene.fluid.density > 0):
        reached = diagnostic["density"]
        return (f"the Reynolds continuation stopped at fluid density {reached:.4g} of "
                f"{scene.fluid.density:g} (fluid.continuation_steps = {scene.fluid.continuation_steps}); "
                "try more continuation steps, a finer mesh, or a smaller fluid.density or inlet velocity")
    if (scene.has_design and scene.effects.coupling == "two-way" and not scene.design.initial
            and "mover" in message):
        return ("the two-way coupled solve failed on the uniform starting design (too soft to "
                "carry the flow's load); start from a saved design: --design FILE or design.initial")
    return ""
