"""A numerical failure in one line: what failed, which element (or that none did), what to try.

:func:`describe` shortens the failure (nested causes grow to hundreds of characters: an
optimizer stage around a load ramp around a mover) to at most ``LIMIT`` characters: where it
happened (the text before its first colon, e.g. the design iteration) and its innermost cause
(the end), with the element the diagnostic names -- the element that broke, the fold, the
smallest det F, or the worst element at the last accepted load -- or, where it names none,
"no element failed". The whole message stays in ``diagnostic.json``. :func:`hint` adds what
to try.
"""

from __future__ import annotations

import re

import movers
from movers.failure import describe_break

LIMIT = 200          # characters of a failure's description on the command line


def failed_element(diagnostic: dict) -> tuple[int, str] | None:
    """``(element, how it is described)`` of the element a failure's diagnostic names, if any."""
    broken = diagnostic.get("broken_element")
    if isinstance(broken, dict) and "element" in broken:
        return int(broken["element"]), (describe_break(broken) if "location" in broken
                                        else f"element {broken['element']} inverted")
    if "folded_elements" in diagnostic and "element" in diagnostic:
        return int(diagnostic["element"]), f"element {diagnostic['element']} folds"
    if "worst_element" in diagnostic and "min_det_F" in diagnostic:
        return (int(diagnostic["worst_element"]),
                f"element {diagnostic['worst_element']}: det F {diagnostic['min_det_F']:.3g}")
    q = diagnostic.get("quality")
    if isinstance(q, dict) and "worst_element" in q and q.get("load", 1.0) != 0:    # load 0: the mesh as it was
        inverted = f"{q['n_inverted']} inverted" if q.get("n_inverted") else "none inverted"
        load = f" at load {q['load']:.3g}" if isinstance(q.get("load"), (int, float)) else ""
        return (int(q["worst_element"]),
                f"mesh{load}: worst element {q['worst_element']}, skewness {q['min_skewness']:.3g}, {inverted}")
    return None


INNER = re.compile(r"(?:failed: |; the last: )")        # where a wrapper quotes the failure it wraps
NAMED = re.compile(r"\belements? \d+|\bno element\b|\bnone inverted\b|\bnone failed\b")
PHRASE = re.compile(r"(?:\b\w+ )?\belement \d+(?: at \([^)]*\) m)?(?: \(skewness [^)]*\))?")


def _shorten(text: str, room: int) -> str:
    """``text`` in ``room`` characters, cut at a word, keeping whole the first phrase that names an
    element (``element 381 at (1.05, 0.475) m (skewness -0.12)``)."""
    if len(text) <= room:
        return text
    phrase = PHRASE.search(text)
    if phrase is None or phrase.end() <= room - 3:
        cut = max(room - 3, phrase.end() if phrase else 0)
        return text[:cut].rsplit(" ", 1)[0] + "..." if phrase is None or phrase.end() < cut else text[:cut] + "..."
    keep = room - (phrase.end() - phrase.start()) - 8
    return text[:max(keep, 0)].rsplit(" ", 1)[0] + " ... " + text[phrase.start():phrase.end()] + "..."


def describe(err, limit: int = LIMIT) -> str:
    """The failure ``err`` (a NumericalError) in at most ``limit`` characters, naming the element
    that failed or saying that none did: a long message keeps where it happened (its first
    part, e.g. the design iteration) and the innermost failure it quotes."""
    text = " ".join(str(err).split())
    element = failed_element(err.diagnostic)
    clause = f" ({element[1]})" if element is not None else " (no element failed)"
    if len(text) + (0 if NAMED.search(text) else len(clause)) > limit:
        head = text.split(": ", 1)[0] if ": " in text else ""
        head = head if len(head) <= limit // 3 and INNER.search(text) else ""
        inner = INNER.split(text)[-1] if head else text
        budget = limit - (len(head) + 6 if head else 0)
        inner = _shorten(inner, budget if NAMED.search(inner) else budget - len(clause))
        text = f"{head}: ... {inner}" if head else inner
    return text if NAMED.search(text) else text + clause


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
    if command == "solve" and diagnostic.get("cold_start"):
        return ("a cold solve starts from rest and ramps the inflow; a design tofsi optimize reached along "
                "its warm-start path may need that path: --from RUN (the run's --output folder) starts from "
                "its final state")
    if command == "solve" and scene.has_design and message.startswith("structure: displacement"):
        return ("the structure is held, but this design is far too soft for the flow's load "
                "(a gray starting design of a soft scene); solve a designed structure: "
                "--design FILE (the design.npy of tofsi optimize), with --stage last")
    return ""
