"""The memory guard: refuse what cannot fit before anything is built, and estimate honestly.

Truths: the measured peak memory of a real solve in a fresh process (the
estimate must be within a factor 1.5 of it) and the exact unknown counts of
the built mesh.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

import tofsi
from tofsi import memory
from tofsi.cli import main
from tofsi.coupled import CoupledModel

SCENE = "examples/scenes/beam_in_channel_optimization.toml"
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("extra", [[], ["effects.coupling=two-way", "mover.name=yeoh"], ["fluid.element=q1q1"]])
def test_unknowns_counted_from_the_axes_match_the_built_model(extra):
    """For every field the model builds, the estimate's unknowns (from the mesh axes alone) are
    its block's size; a two-way scene adds the mesh motion."""
    scene = tofsi.load_scene(SCENE, ["mesh.h_min=0.05", "mesh.h_max=0.05", *extra])
    est = memory.estimate(scene, "solve")
    model = CoupledModel(scene)
    assert est.elements == model.mesh.n_elements
    sizes = {field.title: model.system.by_name[field.name].size for field in model.fields}
    assert est.unknowns == sizes and len(sizes) == (3 if "effects.coupling=two-way" in extra else 2)


def test_the_888k_element_solve_is_refused_in_seconds_with_exit_2(tmp_path, capsys):
    t0 = time.perf_counter()
    status = main(["solve", SCENE, "--set", "mesh.h_min=0.0015", "--set", "mesh.h_max=0.0015",
                   "--output", str(tmp_path)])
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert status == 2 and elapsed < 10
    assert "887,778 elements" in err and "GB" in err and "mesh.h_min" in err
    assert len(err.strip().splitlines()) == 1 and not list(tmp_path.iterdir())


def test_max_memory_option_refuses_a_small_solve(tmp_path, capsys):
    status = main(["solve", SCENE, "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1",
                   "--max-memory", "0.01", "--output", str(tmp_path)])
    assert status == 2 and "0.0 GB are allowed" in capsys.readouterr().err


@pytest.mark.parametrize("element", ["q2q1", "q1q1"])
def test_estimate_within_a_factor_1_5_of_the_measured_peak(element):
    """One real solve in a fresh process (its peak resident memory, VmHWM: unlike ru_maxrss it
    does not inherit the parent's peak across fork and exec), against the estimate."""
    h = 2.0 / 90
    overrides = [f"mesh.h_min={h}", f"mesh.h_max={h}", f"fluid.element={element}"]
    code = (
        "import json, re, tofsi; from tofsi.coupled import CoupledModel\n"
        f"s = tofsi.load_scene({SCENE!r}, {overrides!r})\n"
        "m = CoupledModel(s); m.solve(m.densities())\n"
        "hwm = re.search(r'VmHWM:\\s+(\\d+) kB', open('/proc/self/status').read()).group(1)\n"
        "print(json.dumps(int(hwm) * 1024))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    measured = json.loads(out.stdout.strip().splitlines()[-1])
    est = memory.estimate(tofsi.load_scene(SCENE, overrides), "solve")
    assert 1 / 1.5 <= est.peak_bytes / measured <= 1.5, (est.peak_bytes, measured)


@pytest.mark.parametrize("command,scene", [("solve", SCENE), ("move", "examples/scenes/beam_in_channel.toml")])
def test_estimate_grows_like_n_log_n(command, scene):
    small, large = (memory.estimate(tofsi.load_scene(ROOT / scene, [f"mesh.h_min={h}", f"mesh.h_max={h}",
                                                                    "mesh.growth=1"]), command)
                    for h in (0.05, 0.025))
    ratio = sum(large.factor_entries.values()) / sum(small.factor_entries.values())
    assert 4.0 < ratio < 4.0 * 1.2                  # 4x the unknowns, a little more fill per unknown
