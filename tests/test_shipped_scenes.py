"""Every shipped scene runs as shipped: design scenes solve, optimize a few iterations and pass
check-gradients; mesh-motion scenes move. Scenes above 4000 elements run with ``-m slow``.

The two-way scene's structure is soft (E = 5 kPa), so its uniform gray starting design (stage 0:
one-way, beta 1) moves tens of metres in small-strain elasticity: ``solve`` gives the linear
model's figures (optimize's iteration 0) with a warning on stderr, in solve.json and in run.json
saying that this is not a physical state and what to solve instead (--design FILE).
"""

import json

import pytest

from tofsi.channel import build_mesh

from conftest import ALL_SCENES, load, scene_path

LARGE = 4000


def cases():
    out = []
    for name in ALL_SCENES:
        scene = load(name)
        large = build_mesh(scene.geometry, scene.mesh).n_elements > LARGE
        commands = (["solve", "optimize", "check-gradients"] if scene.has_design
                    else ["move"] if scene.effects.mesh_motion != "none" else ["solve"])
        out += [pytest.param(name, c, id=f"{name}-{c}", marks=[pytest.mark.slow] if large else [])
                for c in commands]
    return out


@pytest.mark.parametrize("name,command", cases())
def test_shipped_scene_runs_as_shipped(name, command, cli, tmp_path):
    extra = ["--set", "optimizer.max_iter=3"] if command == "optimize" else []
    run = cli(command, str(scene_path(name)), "--output", str(tmp_path / "out"), "--json", *extra)
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    if (name, command) == ("beam_in_channel_optimization_fsi", "solve"):
        warning = [ln for ln in run.stderr.splitlines() if ln.startswith("warning:")]
        assert len(warning) == 1 and "exceeds the channel" in warning[0] and "--design FILE" in warning[0]
        assert figures["max_displacement"] > 2.0 and figures["warnings"] == [warning[0][len("warning: "):]]
        record = json.loads((tmp_path / "out" / "run.json").read_text())
        assert record["warnings"] == figures["warnings"]
        history = json.loads(cli("optimize", str(scene_path(name)), "--output", str(tmp_path / "opt"),
                                 "--json", "--set", "optimizer.max_iter=1").stdout)
        assert figures["compliance"] == pytest.approx(history["objective"], rel=1e-9)   # iteration 0
    elif "warnings" in figures:
        assert figures["warnings"] == []
    if command == "check-gradients":
        assert figures["passed"], [r for r in figures["checks"] if not r["passed"]]
    if command == "optimize":
        assert figures["iterations"] == 3 and figures["objective"] > 0
