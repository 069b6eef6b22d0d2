"""Failures name their cause and what to try; --json carries the failed state's figures."""

import json
import subprocess
import sys

import pytest

from conftest import scene_path

FOIL = str(scene_path("foil_in_channel"))
OPT = str(scene_path("beam_in_channel_optimization"))
SPRING_45 = ["mesh.h_min=0.05", "mesh.h_max=0.1", "mover.name=spring", "deformation.mode=rotation",
             "deformation.rotation_deg=45"]


def tofsi(cli, command, scene, overrides, *args, cwd):
    return cli(command, scene, *[a for o in overrides for a in ("--set", o)], *args, cwd=cwd)


def test_a_motion_out_of_the_channel_is_reported_before_moving(cli, tmp_path):
    """The foil (y from 0.475 to 0.525) moved down by 0.6 m leaves the channel."""
    run = tofsi(cli, "move", FOIL, ["deformation.translation=0.6"], "--output", "o", cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1
    assert "deformation.translation = 0.6" in lines[0] and "out of the channel" in lines[0]
    assert "-0.125" in lines[0] and not (tmp_path / "o").exists()      # 0.475 - 0.6


def test_the_spring_analogy_inverting_with_few_increments_suggests_more(cli, tmp_path):
    run = tofsi(cli, "move", FOIL, SPRING_45 + ["mover.spring.increments=1"], "--output", "o", "--json",
                cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 3
    assert lines[-1].startswith("tofsi: numerical failure: spring mover") and "inverted" in lines[-1]
    assert "mover.spring.increments=10" in lines[-1]
    # --json carries the failed state's figures, the same the diagnostic holds
    payload = json.loads(run.stdout)
    quality = json.loads((tmp_path / "o" / "diagnostic.json").read_text())["quality"]
    assert payload["converged"] is False and payload["n_inverted"] == quality["n_inverted"] > 0
    for key in ("min_skewness", "min_area_change", "max_area_change"):
        assert payload[key] == quality[key]
    assert payload["min_skewness"] < 0                                # an inverted corner
    fixed = tofsi(cli, "move", FOIL, SPRING_45 + ["mover.spring.increments=10"], "--output", "p",
                  cwd=tmp_path)
    assert fixed.returncode == 0, fixed.stderr                                # the hint works


def test_a_reynolds_continuation_that_stops_says_where_and_what_to_try(cli, tmp_path):
    run = tofsi(cli, "solve", OPT, ["mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.density=1e3",
                                    "fluid.continuation_steps=2", "fluid.newton_max_iter=6"], "--output", "o",
                cwd=tmp_path)
    last = run.stderr.strip().splitlines()[-1]
    assert run.returncode == 3, run.stderr
    assert "Reynolds continuation stopped at fluid density 500 of 1000" in last
    assert "fluid.continuation_steps=4" in last and "fluid.newton_max_iter" in last
    diagnostic = json.loads((tmp_path / "o" / "diagnostic.json").read_text())
    assert diagnostic["density"] == 500.0


def test_a_failure_is_a_single_line_without_library_error_logs(tmp_path):
    """In a subprocess: log lines reach stderr there."""
    sets = [a for o in SPRING_45 + ["mover.spring.increments=1"] for a in ("--set", o)]
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "move", FOIL, *sets, "--output", "o"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 3
    assert not any(line.startswith(("ERROR", "Traceback")) for line in run.stderr.splitlines())
    assert sum(line.startswith("tofsi:") for line in run.stderr.splitlines()) == 1


@pytest.mark.parametrize("deg,ok", [(30.0, True), (90.0, False)])
def test_rotation_inside_the_channel_is_allowed_and_outside_refused(cli, deg, ok, tmp_path):
    """A 1.2 m foil rotated about its centre (1, 0.5): 30 degrees keeps its corners inside
    (|y - 0.5| <= 0.6 sin 30 + 0.025 cos 30 = 0.32), 90 degrees reaches y = 0.5 +- 0.6."""
    run = tofsi(cli, "move", FOIL, ["geometry.solids=[[0.4, 1.6, 0.475, 0.525]]", "deformation.mode=rotation",
                                    f"deformation.rotation_deg={deg}", "mesh.h_min=0.05", "mesh.h_max=0.1",
                                    "mover.name=linear"], "--output", "o", cwd=tmp_path)
    assert (run.returncode != 2) == ok, run.stderr
