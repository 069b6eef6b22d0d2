"""Every shipped scene runs through the command line: design scenes solve, optimize three
iterations (with their pictures) and pass check-gradients; mesh-motion scenes move. The default
suite runs each at a coarse mesh (a tenth of the channel's smaller side); the scenes as shipped,
at their own meshes, run with ``-m slow``.

The two-way scene's structure is soft (E = 5 kPa), so its uniform gray starting design (stage 0:
one-way, beta 1) moves tens of metres in small-strain elasticity: ``solve`` gives the linear
model's figures (optimize's iteration 0) with a warning on stderr, in solve.json and in run.json
saying that this is not a physical state and what to solve instead (--design FILE).
"""

import json

import pytest

from conftest import ALL_SCENES, load, scene_path

PICTURES = ("convergence.png", "design_0000.png", "design_final.png")


def commands(scene) -> list[str]:
    if scene.has_design:
        return ["solve", "optimize", "check-gradients"]
    return ["move"] if scene.effects.mesh_motion != "none" else ["solve"]


def coarse(scene) -> list[str]:
    h = min(scene.geometry.length, scene.geometry.height) / 10
    return ["--set", f"mesh.h_min={h:g}", "--set", f"mesh.h_max={h:g}"]


def cases():
    out = []
    for name in ALL_SCENES:
        scene = load(name)
        for command in commands(scene):
            out.append(pytest.param(name, command, "coarse", id=f"{name}-{command}-coarse"))
            out.append(pytest.param(name, command, "as shipped", id=f"{name}-{command}-as-shipped",
                                    marks=pytest.mark.slow))
    return out


@pytest.mark.parametrize("name,command,size", cases())
def test_shipped_scene_runs_through_the_command_line(name, command, size, cli, tmp_path):
    scene = load(name)
    mesh = coarse(scene) if size == "coarse" else []
    extra = ["--set", "optimizer.max_iter=3", "--set", "optimizer.output_every=10"] if command == "optimize" else []
    run = cli(command, str(scene_path(name)), *mesh, "--output", str(tmp_path / "out"), "--json", *extra)
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    if (name, command) == ("beam_in_channel_optimization_fsi", "solve"):
        warning = [ln for ln in run.stderr.splitlines() if ln.startswith("warning:")]
        assert len(warning) == 1 and "exceeds the channel" in warning[0] and "--design FILE" in warning[0]
        assert figures["max_displacement"] > 2.0 and figures["warnings"] == [warning[0][len("warning: "):]]
        record = json.loads((tmp_path / "out" / "run.json").read_text())
        assert record["warnings"] == figures["warnings"]
        history = json.loads(cli("optimize", str(scene_path(name)), *mesh, "--output", str(tmp_path / "opt"),
                                 "--json", "--set", "optimizer.max_iter=1").stdout)
        assert figures["compliance"] == pytest.approx(history["objective"], rel=1e-9)   # iteration 0
    elif "warnings" in figures:
        assert figures["warnings"] == []
    if command == "check-gradients":
        assert figures["passed"], [r for r in figures["checks"] if not r["passed"]]
    if command == "optimize":
        assert figures["iterations"] == 3 and figures["objective"] > 0
        for picture in PICTURES:
            assert (tmp_path / "out" / picture).stat().st_size > 1000, picture
