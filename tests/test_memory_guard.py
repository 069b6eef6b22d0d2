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
from tofsi.runs import memory
from tofsi.cli import main
from tofsi.coupling.coupled import CoupledModel

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
        "import json, re, tofsi; from tofsi.coupling.coupled import CoupledModel\n"
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


def test_the_guard_refuses_an_optimize_that_cannot_fit_where_the_solve_would(tmp_path, capsys):
    """At 180 x 90 the optimize's estimate is 1.09x the solve's (measured peaks 1.131 and
    1.060 GB): with a limit between the two, the solve is let through and the optimize
    refused before building anything (exit 2, one line, nothing written)."""
    sets = ["mesh.h_min=0.011111", "mesh.h_max=0.011111"]
    scene = tofsi.load_scene(SCENE, sets)
    solve, optimize = memory.estimate(scene, "solve"), memory.estimate(scene, "optimize")
    assert optimize.peak_gb > 1.05 * solve.peak_gb
    limit = 0.5 * (solve.peak_gb + optimize.peak_gb)
    assert memory.check(scene, "solve", limit) == solve
    t0 = time.perf_counter()
    status = main(["optimize", SCENE, *[a for s in sets for a in ("--set", s)], "--max-memory", f"{limit:.3f}",
                   "--output", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 2 and time.perf_counter() - t0 < 10
    assert "the optimize needs about" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_estimates_per_command_and_backend_follow_the_measured_order():
    """At 130 000 elements: mesh < iterative solve < direct solve < direct optimize; the
    iterative path has no factor entries and grows like n, the direct one like n log n; the
    petsc backend on 4 ranks holds a quarter of the factors per rank."""
    h = 2.0 / 510
    scene = tofsi.load_scene(SCENE, [f"mesh.h_min={h}", f"mesh.h_max={h}"])
    est = {(c, b): memory.estimate(scene, c, b).peak_gb
           for c in ("mesh", "solve", "optimize") for b in ("superlu", "iterative")}
    assert est["mesh", "superlu"] < est["solve", "iterative"] < est["solve", "superlu"] < est["optimize", "superlu"]
    assert memory.estimate(scene, "solve", "iterative").factor_entries == {}
    one, four = memory.estimate(scene, "solve", "petsc", 1), memory.estimate(scene, "solve", "petsc", 4)
    factors = one.peak_bytes - memory.estimate(scene, "solve", "iterative").peak_bytes   # not exact: a check of the split
    assert four.peak_gb < one.peak_gb and four.total_gb > one.peak_gb and factors > 0
    small = memory.estimate(tofsi.load_scene(SCENE, ["mesh.h_min=0.05", "mesh.h_max=0.05"]), "solve", "iterative")
    large = memory.estimate(tofsi.load_scene(SCENE, ["mesh.h_min=0.025", "mesh.h_max=0.025"]), "solve", "iterative")
    growth = (large.peak_bytes - memory.BASE_BYTES) / (small.peak_bytes - memory.BASE_BYTES)
    assert 3.8 < growth < 4.2                      # 4x the elements, linear


def test_mesh_command_is_guarded_too(tmp_path, capsys):
    status = main(["mesh", SCENE, "--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1",
                   "--max-memory", "0.01", "--output", str(tmp_path)])
    assert status == 2 and "the mesh needs about" in capsys.readouterr().err
