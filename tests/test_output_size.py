"""The output-size estimate against the files runs write (it refuses a run below half of it)."""

import os

import pytest

import tofsi
from tofsi.runs.output_size import CLEARLY_SHORT, estimate

from conftest import scene_path

RUNS = {"mesh": ("foil_in_channel", []), "move": ("foil_in_channel", []),
        "solve": ("beam_in_channel_optimization", []),
        "two-way solve": ("beam_in_channel_optimization_fsi", ["--stage", "last", "structure.youngs_modulus=1e5"]),
        "optimize": ("beam_in_channel_optimization", ["optimizer.max_iter=3", "optimizer.output_every=2",
                                                      "design.stage_iterations=2"])}


@pytest.mark.parametrize("command", list(RUNS))
@pytest.mark.parametrize("h", [0.1, 0.05])
def test_the_estimate_is_within_a_factor_two_of_what_a_run_writes(cli, command, h, tmp_path):
    """Measured: the files of the run, byte for byte. The estimate must never refuse a run
    that fits (written >= CLEARLY_SHORT x estimate) and must mean something (<= 2 x)."""
    name, extra = RUNS[command]
    command = command.split()[-1]
    options = [a for a in extra if a.startswith("--") or a == "last"]
    extra = [a for a in extra if a not in options]
    mesh = [f"mesh.h_min={h}", f"mesh.h_max={h}"]
    args = [a for o in mesh + extra for a in ("--set", o)] + options
    run = cli(command, scene_path(name), "--output", "out", "-q", *args, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    written = {n: os.path.getsize(tmp_path / "out" / n) for n in os.listdir(tmp_path / "out")}
    est = estimate(tofsi.load_scene(scene_path(name), mesh + extra), command)
    assert set(written) == set(est.files)                  # the estimate knows every file
    ratio = sum(written.values()) / est.total
    assert CLEARLY_SHORT <= ratio <= 2.0, (ratio, written, est.files)
