"""The structure's material is an object from a registry (``structure.model``, a stage's
``design.structure_model``): a material defined in this file alone -- one class -- is chosen
by the scene, solves, and its gradient passes the Taylor test; renamed keys are accepted
with a warning."""

import numpy as np
import pytest

import tofsi
from tofsi.core.errors import InputError
from tofsi.core.registry import MATERIALS
from tofsi.physics.materials import FiniteStrain, SmallStrain

from conftest import load
from gradient_checks import check_total_derivative

COARSE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.beta=[1.0]"]


class DoubledSmallStrain(SmallStrain):
    """Small strain with every modulus doubled, ``R_int = 2 K_s(rho) u``: defined here and nowhere else."""

    name = "doubled-small-strain"

    def element_forces(self, u, moduli):
        return 2.0 * super().element_forces(u, moduli)

    def tangent(self, u, rho, simp):
        st = self.structure
        return st.bc.matrix(2.0 * st.K0 * simp(rho)[:, None, None])


@pytest.fixture
def doubled():
    MATERIALS.register(DoubledSmallStrain)
    yield DoubledSmallStrain
    MATERIALS.unregister(DoubledSmallStrain.name)


def test_the_built_in_materials_are_registry_entries_with_their_capabilities():
    assert MATERIALS.get("linear") is SmallStrain and not SmallStrain.nonlinear
    assert MATERIALS.get("neo-hookean") is FiniteStrain and FiniteStrain.nonlinear
    with pytest.raises(InputError, match="structure.model"):
        load("beam_in_channel_optimization", "structure.model=rubber")


def test_a_material_defined_in_a_test_file_solves_as_its_physics_says(doubled):
    """Doubling every modulus is the linear material at twice ``E0`` (and ``Emin``): the same
    displacement to round-off, and not the linear one at ``E0``."""
    E0 = load("beam_in_channel_optimization").structure.youngs_modulus
    mine = tofsi.Problem(load("beam_in_channel_optimization", *COARSE, "structure.model=doubled-small-strain"))
    stiffer = tofsi.Problem(load("beam_in_channel_optimization", *COARSE, f"structure.youngs_modulus={2 * E0}"))
    plain = tofsi.Problem(load("beam_in_channel_optimization", *COARSE))
    gamma = np.random.default_rng(1).uniform(0.3, 0.9, mine.n_design)
    u, u2, u1 = (p.solve(gamma).u for p in (mine, stiffer, plain))
    assert np.abs(u - u2).max() <= 1e-10 * np.abs(u2).max()
    assert np.abs(u - u1).max() > 0.1 * np.abs(u1).max()
    assert mine.model.system.by_name["u"].material.name == "doubled-small-strain"


def test_a_material_defined_in_a_test_file_has_an_exact_gradient(doubled):
    P = tofsi.Problem(load("beam_in_channel_optimization", *COARSE, "structure.model=doubled-small-strain"))
    rng = np.random.default_rng(3)
    gamma = rng.uniform(0.3, 0.9, P.n_design)
    taylor, cd_error, _ = check_total_derivative(P, gamma, rng.normal(size=P.n_design))
    assert taylor.min_rate > 1.9, taylor
    assert cd_error < 1e-6


def test_a_stage_of_the_schedule_takes_a_registered_material(doubled):
    P = tofsi.Problem(load("beam_in_channel_optimization", *COARSE,
                           'design.structure_model=["linear", "doubled-small-strain"]', "design.beta=[1.0, 1.0]"))
    from tofsi.coupling.coupled import continuation
    P.set_stage(continuation(P.scene, 1))
    assert P.model.system_for(P.stage).by_name["u"].material.name == "doubled-small-strain"
    assert P.model.system.by_name["u"].material.name == "linear"          # stage 0: the scene's


@pytest.mark.parametrize("old,new,value", [("coupled.linear_solver", "coupled.jacobian_solver", "direct"),
                                           ("mover.yeoh.linear_solver", "mover.yeoh.tangent_solver", "amg")])
def test_a_renamed_key_is_accepted_with_a_one_line_warning(old, new, value):
    with pytest.warns(FutureWarning, match=f"{old} is an old name: write {new}") as caught:
        scene = load("beam_in_channel_optimization_fsi", f"{old}={value}")
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    table, key = new.rsplit(".", 1)
    record = scene.coupled if table == "coupled" else scene.mover.params["yeoh"]
    assert getattr(record, key) == value
    with pytest.raises(InputError, match="old name"):
        load("beam_in_channel_optimization_fsi", f"{old}={value}", f"{new}=block" if table == "coupled"
             else f"{new}=direct")


def test_the_command_line_shows_an_old_key_as_one_line(tmp_path):
    import subprocess
    import sys
    from conftest import scene_path
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "mesh", str(scene_path("double_pipe")),
                          "--set", "coupled.linear_solver=direct", "--output", str(tmp_path)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stderr.splitlines() == ["warning: coupled.linear_solver is an old name: write coupled.jacobian_solver"]
