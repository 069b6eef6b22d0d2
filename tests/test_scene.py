"""Scene loading and validation: every bad value is rejected with its key."""

import math

import pytest

import tofsi
from tofsi.core.errors import InputError
from tofsi.scene.scene import parse_override

from conftest import ALL_SCENES, load, scene_path


def test_shipped_scenes_load_frozen(shipped_scene):
    assert shipped_scene.name
    with pytest.raises(AttributeError):
        shipped_scene.mesh.h_min = 1.0          # frozen


def test_the_three_required_scenes_are_shipped():
    assert {"beam_in_channel", "foil_in_channel", "beam_in_channel_optimization"} <= set(ALL_SCENES)


def test_scene_geometry_matches_the_issue():
    beam = load("beam_in_channel")
    assert beam.geometry.solids == ((0.95, 1.05, 0.0, 0.5),)
    assert beam.geometry.holes == ((0.975, 1.025, 0.0, 0.1),)
    assert beam.deformation.tip_displacement == 0.15
    foil = load("foil_in_channel")
    assert foil.geometry.solids == ((0.75, 1.25, 0.475, 0.525),)
    assert (foil.deformation.translation, foil.deformation.rotation_deg,
            foil.deformation.bending_tip) == (0.2, 30.0, 0.15)
    opt = load("beam_in_channel_optimization")
    assert opt.geometry.design == (0.3, 1.7, 0.0, 0.8)
    assert opt.geometry.solids == ((0.975, 1.025, 0.0, 0.5),)
    assert (opt.fluid.density, opt.fluid.viscosity, opt.fluid.inlet_velocity) == (1.0, 1.0, 1.0)
    # E = 1e7 Pa (1e5 before the momentum-consistent load): one-way designs do not depend on E,
    # and the uniform gray start must move far less than the channel under the full flow force
    assert (opt.structure.youngs_modulus, opt.structure.poisson_ratio) == (1e7, 0.3)


def test_overrides_are_validated_like_the_file():
    s = load("foil_in_channel", "mover.name=spring", "mover.spring.increments=5",
             "deformation.mode=rotation", "mover.layers=[2.0, 1.5]")
    assert s.mover.name == s.effects.mesh_motion == "spring"
    assert s.mover.options.increments == 5
    assert s.mover.layers == (2.0, 1.5)
    assert s.deformation.mode == "rotation"


def test_mover_name_and_effects_mesh_motion_are_one_setting():
    s = load("beam_in_channel_optimization", "mover.name=yeoh")
    assert s.effects.mesh_motion == "yeoh"
    s = load("foil_in_channel", "effects.mesh_motion=none")
    assert s.mover.name == "none" and s.mover.options is None


BAD = [
    ("mesh.h_mni=0.1", "mesh.h_mni", "unknown key"),
    ("mesh.h_min=-0.01", "mesh.h_min", "0 < value"),
    ("mesh.h_min=0", "mesh.h_min", "0 < value"),
    ("mesh.h_min=nan", "mesh.h_min", "finite"),
    ("mesh.h_max=inf", "mesh.h_max", "finite"),
    ("mesh.h_min=1.0", "mesh.h_min", "h_max"),
    ("geometry.length=-2", "geometry.length", "0 < value"),
    ("mover.name=sprung", "mover.name", "'spring'"),
    ("mover.yeoh.A10=0", "mover.yeoh.A10", "0 < value"),
    ("mover.yeoh.kappa=-1", "mover.yeoh.kappa", "0 < value"),
    ("mover.spring.diagonals='1-2'", "mover.spring.diagonals", "'selective'"),
    ("mover.layers=[2, -1]", "mover.layers[1]", "0 < value"),
    ("structure.poisson_ratio=0.5", "structure.poisson_ratio", "value < 0.5"),
    ("design.volume_fraction=1.2", "design.volume_fraction", "value < 1"),
    ("design.volume_fraction=0", "design.volume_fraction", "0 < value"),
    ("geometry.design=[0.3, 2.5, 0.0, 0.8]", "geometry.design", "inside the channel"),
    ("geometry.solids=[[1.0, 0.9, 0.0, 0.5]]", "geometry.solids[0]", "x0 < x1"),
    ("deformation.mode=twist", "deformation.mode", "'rotation'"),
    ("mesh.growth='fast'", "mesh.growth", "expected a number"),
    ("mover.yeoh.increments=2.5", "mover.yeoh.increments", "whole number"),
    ("fluid.viscosity=0", "fluid.viscosity", "0 < value"),
    ("unknown_table.x=1", "unknown_table", "unknown key"),
]


@pytest.mark.parametrize("override,key,allowed", BAD)
def test_bad_values_are_rejected_with_their_key(override, key, allowed):
    with pytest.raises(InputError) as err:
        tofsi.load_scene(scene_path("beam_in_channel_optimization" if "design" in override
                                    else "foil_in_channel"), [override])
    assert err.value.key == key
    assert allowed in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_and_malformed_files_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        tofsi.load_scene(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(InputError, match="not valid TOML"):
        tofsi.load_scene(bad)
    nameless = tmp_path / "nameless.toml"
    nameless.write_text("[mesh]\nh_min = 0.1\n")
    with pytest.raises(InputError) as err:
        tofsi.load_scene(nameless)
    assert err.value.key == "name"


@pytest.mark.parametrize("text,path,value", [
    ("mover.name=spring", ["mover", "name"], "spring"),
    ("mover.yeoh.A20=1e3", ["mover", "yeoh", "A20"], 1000.0),
    ("mover.layers=[2.2, 1.45]", ["mover", "layers"], [2.2, 1.45]),
    ("deformation.scale=false", ["deformation", "scale"], False),
    ("mesh.h_min=nan", ["mesh", "h_min"], math.nan),
])
def test_override_values_are_parsed_as_toml(text, path, value):
    p, v = parse_override(text)
    assert p == path
    assert v == value or (isinstance(value, float) and math.isnan(value) and math.isnan(v))


def test_override_without_equals_sign_is_rejected():
    with pytest.raises(InputError, match="KEY=VALUE"):
        parse_override("mover.name")


def test_the_scene_reference_in_the_docs_is_current():
    from pathlib import Path
    from tofsi.scene.scene import reference_table
    docs = (Path(__file__).resolve().parents[1] / "docs" / "scenes.md").read_text()
    assert reference_table() in docs, "regenerate docs/scenes.md from tofsi.scene.scene.reference_table()"


def test_loading_a_scene_reads_the_fields_tables_without_importing_physics():
    """The fields' tables ([fluid], [structure], [mover]) come from their field modules; loading
    a scene imports those modules but no physics (a field imports its physics when built)."""
    import subprocess
    import sys
    code = ("import sys, tofsi; s = tofsi.load_scene(sys.argv[1]); "
            "print(s.fluid.viscosity, s.structure.youngs_modulus, s.mover.name, "
            "[m for m in sys.modules if m.startswith('tofsi.physics')])")
    run = subprocess.run([sys.executable, "-c", code, str(scene_path("beam_in_channel_optimization_fsi"))],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    scene = load("beam_in_channel_optimization_fsi")
    assert run.stdout.split() == [str(scene.fluid.viscosity), str(scene.structure.youngs_modulus),
                                  scene.mover.name, "[]"]
