"""Every shipped scene runs as shipped: design scenes solve, optimize a few iterations and pass
check-gradients; mesh-motion scenes move. Scenes above 4000 elements run with ``-m slow``.

One exception, stated: the two-way scene's structure is soft (E = 5 kPa), so its uniform gray
starting design moves tens of metres in small-strain elasticity; ``solve`` refuses it (exit 3)
in one line saying what to solve instead (a designed structure, --design FILE).
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
    if (name, command) == ("beam_in_channel_optimization_fsi", "solve"):
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 3 and "exceeds the channel" in lines[-1] and "--design FILE" in lines[-1]
        return
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    if command == "check-gradients":
        assert figures["passed"], [r for r in figures["checks"] if not r["passed"]]
    if command == "optimize":
        assert figures["iterations"] == 3 and figures["objective"] > 0
