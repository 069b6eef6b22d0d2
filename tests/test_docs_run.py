"""Docs that run: every code block of README.md and every script in examples/ (small sizes).
The runs are acceptance tests (``pytest -m acceptance``, which CI runs after the default suite)."""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
BLOCKS = re.findall(r"^```(\w+)\n(.*?)^```", README, re.S | re.M)
# Small versions of the README's command lines: overrides per scene, appended to each command.
SMALL = {"foil_in_channel": ["mesh.h_min=0.05", "mesh.h_max=0.1"],
         "beam_in_channel": ["mesh.h_min=0.05", "mesh.h_max=0.1", "tune.layers=2", "tune.max_solves=4"],
         "beam_in_channel_optimization": ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.15",
                                          "optimizer.max_iter=4", "design.stage_iterations=2"]}
EXAMPLE_ARGS = {"optimize_beam_in_channel.py": [], "optimize_fsi.py": [], "compare_movers.py": [],
                "compare_mesh_motion.py": [], "compare_void_interpolation.py": [],
                "move_foil.py": ["rotation"], "mesh_motion_study.py": ["all", "--jobs", "2"],
                "tuning_band_study.py": ["all", "--jobs", "1"], "optimize_large_deformation.py": [],
                "compare_large_deformation.py": ["--jobs", "2"]}


PICTURES = re.findall(r"\]\(docs/img/optimization/([\w-]+)/([\w.-]+\.png)\)", README)
"""README pictures an example writes: (its default output folder's name, the file's name)."""


def default_output(script: str) -> str | None:
    found = re.search(r'default=Path\("results/([\w-]+)"\)', (ROOT / "examples" / script).read_text())
    return found[1] if found else None


def env():
    return {**os.environ, "PYTHONPATH": str(ROOT), "TOFSI_EXAMPLE_SMALL": "1"}


def commands(block: str) -> list[list[str]]:
    """Shell command lines of a block (continuations joined, comments dropped)."""
    text = block.replace("\\\n", " ")
    return [shlex.split(line, comments=True) for line in text.splitlines() if shlex.split(line, comments=True)]


def test_the_first_bash_block_is_the_ci_commands():
    """.ci/run executes the first bash block: the install with the headline (two-way, large-deformation) example, then the
    default tests; then it runs the acceptance tests. They are not rerun here (the example runs at a
    small size in this file, the tests are this suite)."""
    language, block = BLOCKS[0]
    lines = commands(block)
    assert language == "bash" and len(lines) == 2
    assert "examples/optimize_large_deformation.py" in lines[0] and lines[1][:3] == ["python3", "-m", "pytest"]
    assert (ROOT / "examples" / "optimize_large_deformation.py").is_file()
    # then the acceptance tests, as README's text below the block says
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()
    assert "python -m pytest -n 2 -m acceptance" in ci and "`python -m pytest -n 2 -m acceptance`" in README
    # and last the PETSc tests on two ranks (.ci/petsc installs Debian's PETSc or says why it skips)
    assert ci[-1] == "bash .ci/petsc" and ci.index("python -m pytest -n 2 -m acceptance") < len(ci) - 1


@pytest.mark.acceptance
@pytest.mark.parametrize("index", [i for i, (lang, _) in enumerate(BLOCKS) if lang == "python"])
def test_readme_python_blocks_run(index):
    run = subprocess.run([sys.executable, "-c", BLOCKS[index][1]], capture_output=True, text=True,
                         cwd=ROOT, env=env())
    assert run.returncode == 0, run.stderr


@pytest.mark.acceptance
def test_readme_command_lines_run_at_a_small_size(tmp_path):
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    lines = [c for lang, block in BLOCKS[1:] if lang == "bash" for c in commands(block)]
    assert lines and all(c[0] == "tofsi" for c in lines)
    for command in lines:
        scene = Path(command[2]).stem
        small = [a for o in SMALL[scene] for a in ("--set", o)]
        run = subprocess.run([sys.executable, "-m", "tofsi.cli", *command[1:], *small], capture_output=True,
                             text=True, cwd=tmp_path, env=env())
        assert run.returncode == 0, f"{shlex.join(command)}: {run.stderr}"
    assert (tmp_path / "results" / "beam_solved" / "solve.json").is_file()


@pytest.mark.acceptance
@pytest.mark.parametrize("script", sorted(p.name for p in (ROOT / "examples").glob("*.py")))
def test_every_example_runs_at_a_small_size(script, tmp_path):
    assert script in EXAMPLE_ARGS, f"add {script}'s arguments to EXAMPLE_ARGS"
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, str(ROOT / "examples" / script), *EXAMPLE_ARGS[script],
                          "--output", str(out)], capture_output=True, text=True, cwd=tmp_path, env=env())
    assert run.returncode == 0, run.stderr
    assert out.is_dir() and any(out.rglob("*.*"))
    for folder, name in PICTURES:                        # README's pictures carry the names written
        if folder == default_output(script):
            assert (out / name).is_file(), f"README shows {name}, which {script} does not write"


def test_readme_pictures_are_named_as_an_example_writes_them():
    """The headline's pictures were fsi_design.png while the example writes design_final.png: each
    README picture of a run sits in a folder named as an example's results folder."""
    folders = {default_output(p.name) for p in (ROOT / "examples").glob("*.py")}
    assert PICTURES and {folder for folder, _ in PICTURES} <= folders
    assert len(re.findall(r"\]\(docs/img/optimization/", README)) == len(PICTURES)
