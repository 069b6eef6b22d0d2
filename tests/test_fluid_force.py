"""The fluid's force on the solid: momentum-consistent, against an independent no-slip body.

The Brinkman computation and the no-slip reference (tests/no_slip.py: the body cut out of the
same mesh, the reaction of its boundary velocity dofs) are different formulations; the
reaction load must approach the no-slip force as the friction grows. Under refinement at a
fixed friction it does not: the gap follows a slip length mu / (alpha h) (docs/design.md),
so the refinement test scales alpha_max with h^-2 and states the fixed-friction law too.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from tofsi.coupling.coupled import CoupledModel
from tofsi.mesh.structured import SOLID

from conftest import load, scene_path
from no_slip import NoSlipReference

FOIL = ["effects.fluid=stokes", "effects.structure=none"]
BEAM = ["effects.fluid=stokes", "effects.structure=none", "geometry.holes=[]"]


def brinkman_and_no_slip(name, overrides, alphas):
    """Drag and lift of the Brinkman reaction load for each alpha_max, and the no-slip force."""
    out = []
    for alpha in alphas:
        model = CoupledModel(load(name, *overrides, f"fluid.alpha_max={alpha}"))
        state = model.solve(model.densities())
        figures = model.figures(state)
        out.append((figures["drag"], figures["lift"]))
    ref = NoSlipReference(model.flow, model.mesh.region == SOLID)
    ref.solve()
    return np.array(out), ref.force()


def test_foil_drag_converges_to_the_no_slip_drag_as_the_friction_grows():
    alphas = [1e4, 1e5, 1e6, 1e7, 1e8, 1e9]
    forces, no_slip = brinkman_and_no_slip("foil_in_channel", FOIL, alphas)
    assert no_slip[0] == pytest.approx(15.397, abs=2e-3)            # the reference itself
    gap = np.abs(forces[:, 0] - no_slip[0]) / no_slip[0]
    assert np.all(np.diff(gap) < 0), gap                            # monotone in alpha_max
    assert np.all(gap[np.array(alphas) >= 1e7] < 5e-3), gap          # within 0.5 % from 1e7
    assert gap[-1] < 1e-4 and gap[-2] / gap[-1] == pytest.approx(10.0, rel=0.1)   # ~ 1/alpha
    assert np.abs(forces[:, 1]).max() < 1e-9 * no_slip[0]           # symmetric foil: no lift


@pytest.mark.parametrize("fluid", ["stokes", "navier-stokes"])
def test_beam_drag_and_lift_match_the_no_slip_body_at_high_friction(fluid):
    """The beam stands on the floor: the wall's support reaction is not fluid load (today's
    stress-divergence lift counted 2.44 N/m of floor and notch pressure)."""
    overrides = [*BEAM, f"effects.fluid={fluid}"]
    forces, no_slip = brinkman_and_no_slip("beam_in_channel", overrides, [1e8])
    drag, lift = forces[0]
    assert drag == pytest.approx(no_slip[0], rel=1e-2)
    assert lift == pytest.approx(no_slip[1], rel=1e-2)
    assert abs(lift) > 1.0                                           # a real lift, not noise
    old = CoupledModel(load("beam_in_channel", *overrides, "fluid.alpha_max=1e8",
                            "structure.load=stress-divergence"))
    old_drag = old.figures(old.solve(old.densities()))["drag"]
    assert abs(old_drag - no_slip[0]) > 5 * abs(drag - no_slip[0])  # the old form is far off


def test_refinement_with_the_friction_scaled_as_h_squared_shrinks_the_gap():
    """alpha h^2 / mu fixed: the gap halves per refinement. At fixed alpha it grows like 1/h
    (slip length mu / (alpha h)); both laws are asserted."""
    scaled, fixed = [], []
    for h in (0.025, 0.0125, 0.00625):
        for alpha, rows in ((1e5 * (0.025 / h) ** 2, scaled), (1e8, fixed)):
            forces, no_slip = brinkman_and_no_slip("foil_in_channel", [*FOIL, f"mesh.h_min={h}"], [alpha])
            rows.append(abs(forces[0, 0] - no_slip[0]) / no_slip[0])
    scaled, fixed = np.array(scaled), np.array(fixed)
    assert np.all(scaled[1:] / scaled[:-1] < 0.6), scaled
    assert np.all((fixed[1:] / fixed[:-1] > 1.5) & (fixed[1:] / fixed[:-1] < 2.3)), fixed
    assert fixed.max() < 1e-3


def test_solve_reports_drag_and_lift_as_the_load_resultant_with_and_without_the_structure(tmp_path):
    base = ["mesh.h_min=0.05", "mesh.h_max=0.1", "effects.fluid=navier-stokes"]
    scene = load("beam_in_channel", *base, "effects.structure=linear-elastic", "structure.youngs_modulus=1e6")
    model = CoupledModel(scene)
    state = model.solve(model.densities())
    f = model.structure.load(state.w, None, state.rho, state.params)
    figures = model.figures(state)
    assert figures["drag"] == pytest.approx(f[0::2].sum(), rel=1e-14, abs=1e-14)
    assert figures["lift"] == pytest.approx(f[1::2].sum(), rel=1e-14, abs=1e-14)
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "solve", str(scene_path("foil_in_channel")),
                          *sum([["--set", s] for s in [*base, "effects.fluid=stokes"]], []),
                          "--output", str(tmp_path), "--json"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    foil = json.loads(run.stdout)
    assert foil["drag"] > 0 and abs(foil["lift"]) < 1e-9 * foil["drag"]      # no structure effect


def test_a_floating_structure_is_an_input_error_naming_the_clamp(tmp_path):
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "solve", str(scene_path("foil_in_channel")),
                          "--set", "effects.fluid=navier-stokes", "--set", "effects.structure=linear-elastic",
                          "--output", str(tmp_path)], capture_output=True, text=True)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "structure.clamped" in lines[0]
    assert not any(tmp_path.iterdir())                               # nothing computed, nothing written
