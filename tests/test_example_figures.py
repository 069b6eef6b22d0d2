"""Issue 36, item 1: an example prints the figures of the movers it names.

``examples/move_foil.py`` printed the Yeoh mover's figures for all three movers
(``run_move(scene, setup=...)`` moved with the setup's mover whatever the scene
said). Each printed figure is compared with ``tofsi move`` of the same settings
(the command's own figures, or for a move that inverts elements its exit-3
quality keys).
"""

import json
import re
import runpy

import pytest

from conftest import SCENES, scene_path

LINE = re.compile(r"^\s+(\w+)\s+min skewness\s+(-?[\d.]+)\s+inverted\s+(\d+)\s+area change (-?[\d.]+) \.\. (-?[\d.]+)")


@pytest.mark.acceptance
def test_move_foil_prints_each_movers_own_figures(cli, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TOFSI_EXAMPLE_SMALL", "1")
    example = runpy.run_path(str(SCENES.parent / "move_foil.py"))
    rows = example["main"]("rotation", tmp_path / "example")
    printed = {m[1]: m.groups()[1:] for m in map(LINE.match, capsys.readouterr().out.splitlines()) if m}
    assert sorted(printed) == sorted(r["mover"] for r in rows) == ["linear", "spring", "yeoh"]
    seen = set()
    for mover, (skew, inverted, low, high) in printed.items():
        run = cli("move", scene_path("foil_in_channel"), "--json", "--output", tmp_path / mover,
                  *[a for o in example["MESH"] + ["deformation.mode=rotation", f"mover.name={mover}"]
                    for a in ("--set", o)])
        assert run.returncode in (0, 3), run.stderr
        figures = json.loads(run.stdout)
        assert float(skew) == pytest.approx(figures["min_skewness"], abs=5e-4), mover
        assert int(inverted) == figures["n_inverted"], mover
        assert float(low) == pytest.approx(figures["min_area_change"], abs=5e-4), mover
        assert float(high) == pytest.approx(figures["max_area_change"], abs=5e-4), mover
        seen.add(skew)
    assert len(seen) == 3                          # three movers, three different meshes


def test_a_motion_setup_of_another_scene_is_refused():
    """The cause: a setup built for one mover, used with a scene naming another."""
    import tofsi
    from tofsi.coupling.motion import motion_setup, run_move
    small = ["mesh.h_min=0.1", "mesh.h_max=0.2"]
    yeoh = tofsi.load_scene(scene_path("foil_in_channel"), small)
    spring = tofsi.load_scene(scene_path("foil_in_channel"), small + ["mover.name=spring"])
    with pytest.raises(ValueError, match="built for 'foil_in_channel' with the yeoh mover"):
        run_move(spring, setup=motion_setup(yeoh))
