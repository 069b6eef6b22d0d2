"""Every shipped scene runs through the command line: design scenes solve, optimize three
iterations (with their pictures) and pass check-gradients; mesh-motion scenes (a prescribed
deformation) move; the others (the benchmarks' fixed structures) solve. The default
suite runs each at a coarse mesh (a tenth of the channel's smaller side); the scenes as shipped,
at their own meshes, run with ``-m slow``.

The two-way scenes' structures are soft (E = 5 and 1.5 kPa), so their uniform gray starting design (stage 0:
one-way, beta 1) moves tens of metres in small-strain elasticity: ``solve`` writes the linear
model's figures (optimize's iteration 0) marked ``physical: false`` with a warning on stderr, in
solve.json and in run.json saying what to solve instead (--design FILE), and exits 5 unless
``--allow-unphysical`` accepts them; ``optimize``'s three one-way iterations end on such a state
and exit 5 too.
"""

import json

import pytest

from conftest import ALL_SCENES, load, scene_path

PICTURES = ("convergence.png", "design_0000.png", "design_final.png")
SOFT = ("beam_in_channel_optimization_fsi", "beam_in_channel_optimization_large")   # gray start: unphysical
COARSE_EXTRA = {("beam_in_channel_optimization_large", "check-gradients"): ["structure.youngs_modulus=1.5e4",
                                                                           "design.filter_radius=0.15"]}
"""At a tenth of the channel's height per element the large-deformation scene's 1.5 kPa design,
reached by its one-way stages, cannot be carried two-way (the mesh of 10 x 20 elements folds at
about 0.6 of the inflow); ten times stiffer it can. Its filter radius (0.075 m) is below this
mesh's element size, where the filter averages nothing (the volume's Taylor rate then fell to
1.74 at beta 8): 1.5 elements here, as the scene's radius is at 40 x 20. As shipped it runs
unchanged (slow)."""


def commands(scene) -> list[str]:
    if scene.has_design:
        return ["solve", "optimize", "check-gradients"]
    return ["move"] if scene.deformation.mode != "none" else ["solve"]


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
    if size == "coarse":
        mesh += [a for key in COARSE_EXTRA.get((name, command), []) for a in ("--set", key)]
    extra = ["--set", "optimizer.max_iter=3", "--set", "optimizer.output_every=10"] if command == "optimize" else []
    run = cli(command, str(scene_path(name)), *mesh, "--output", str(tmp_path / "out"), "--json", *extra)
    unphysical = command in ("solve", "optimize") and name in SOFT      # optimize: 3 one-way iterations
    assert run.returncode == (5 if unphysical else 0), run.stderr
    figures = json.loads(run.stdout)
    assert figures.get("physical", True) is not unphysical
    if unphysical and command == "optimize":
        assert "no physical state" in run.stderr and "exceeds the channel" in figures["unphysical"]
    elif unphysical:
        warning = [ln for ln in run.stderr.splitlines() if ln.startswith("warning:")]
        assert len(warning) == 1 and "exceeds the channel" in warning[0] and "--design FILE" in warning[0]
        assert "--allow-unphysical" in warning[0]
        accepted = cli(command, str(scene_path(name)), *mesh, "--output", str(tmp_path / "ok"), "--json",
                       "--allow-unphysical")
        assert accepted.returncode == 0 and json.loads(accepted.stdout)["physical"] is False
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
