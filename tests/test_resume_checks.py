"""--resume continues the same problem or refuses in one line, naming what differs."""

import json
import os
import shutil

import numpy as np
import pytest

import tofsi
from tofsi.core.errors import InputError
from tofsi.optimization.optimize import Optimizer
from tofsi.optimization.resume import check_checkpoint, read_checkpoint

from conftest import scene_path

OPT = str(scene_path("beam_in_channel_optimization"))
TINY = ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.25", "design.stage_iterations=4",
        "optimizer.max_iter=10"]


def optimize(cli, *args, cwd):
    sets = [a for o in TINY for a in ("--set", o)]
    return cli("optimize", OPT, "--output", "out", *sets, *args, cwd=cwd)


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory):
    """A run stopped after 6 of 10 iterations (checkpoint inside the second stage)."""
    folder = tmp_path_factory.mktemp("interrupted") / "out"
    scene = tofsi.load_scene(OPT, TINY)

    def stop(it):
        if it.iteration == 5:
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        Optimizer(tofsi.Problem(scene), folder, on_iteration=stop).run()
    return folder


def copy_of(interrupted, tmp_path):
    shutil.copytree(interrupted, tmp_path / "out")
    return tmp_path / "out"


def test_resume_with_a_changed_volume_bound_is_refused_naming_the_key(cli, interrupted, tmp_path):
    """The reproduction: --resume --set design.volume_fraction=0.3 replayed under 0.2 and went on
    under 0.3 (exit 0). Now: exit 2, one line naming the key and both values; nothing changes."""
    out = copy_of(interrupted, tmp_path)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    run = optimize(cli, "--resume", "--set", "design.volume_fraction=0.3", cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "design.volume_fraction: 0.2 -> 0.3" in lines[0]
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_every_differing_key_is_named(cli, interrupted, tmp_path):
    copy_of(interrupted, tmp_path)
    run = optimize(cli, "--resume", "--set", "design.eta=0.4", "--set", "fluid.viscosity=2", cwd=tmp_path)
    assert run.returncode == 2 and "design.eta" in run.stderr and "fluid.viscosity" in run.stderr


def test_keys_that_cannot_change_the_replayed_history_may_differ(cli, interrupted, tmp_path):
    """max_iter may grow: the resumed history holds the checkpoint's 6 iterations bit for bit."""
    out = copy_of(interrupted, tmp_path)
    replayed = json.loads((out / "history.json").read_text())
    run = optimize(cli, "--resume", "--set", "optimizer.max_iter=12", "--set", "optimizer.output_every=4",
                   "--json", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    history = json.loads((out / "history.json").read_text())
    def without_time(rows):
        return [{k: v for k, v in r.items() if k != "time_s"} for r in rows]
    assert len(replayed) == 6 and len(history) == 12
    assert without_time(history[:6]) == without_time(replayed)
    record = json.loads((out / "run.json").read_text())
    assert record["exit_status"] == 0 and record["stop_reason"] == "max_iter"


def test_max_iter_below_the_checkpoint_is_refused(cli, interrupted, tmp_path):
    copy_of(interrupted, tmp_path)
    run = optimize(cli, "--resume", "--set", "optimizer.max_iter=3", cwd=tmp_path)
    assert run.returncode == 2 and "optimizer.max_iter" in run.stderr and ">= 6" in run.stderr


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty", "no record"])
def test_an_unreadable_checkpoint_exits_2_in_one_line(cli, damage, interrupted, tmp_path):
    out = copy_of(interrupted, tmp_path)
    path = out / "checkpoint.npz"
    data = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(os.urandom(4096))
    elif damage == "empty":
        path.write_bytes(b"")
    else:                                             # an older tofsi's checkpoint: no scene record
        with np.load(path) as npz:
            arrays = dict(npz)
        meta = json.loads(str(arrays["meta"]))
        del meta["identity"]
        arrays["meta"] = np.array(json.dumps(meta))
        with open(path, "wb") as fh:
            np.savez(fh, **arrays)
    run = optimize(cli, "--resume", cwd=tmp_path)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1 and "--resume" in lines[0], run.stderr
    assert "Traceback" not in run.stderr


def test_a_checkpoint_of_another_mesh_is_refused(cli, interrupted, tmp_path):
    out = copy_of(interrupted, tmp_path)
    run = optimize(cli, "--resume", "--set", "mesh.h_min=0.05", "--set", "mesh.h_max=0.05",
                   cwd=tmp_path)
    assert run.returncode == 2 and "mesh.h_min" in run.stderr and "mesh.h_max" in run.stderr
    # the same scene, but the recorded mesh is not this one (a checkpoint copied from elsewhere)
    meta, data = read_checkpoint(out / "checkpoint.npz")
    problem = tofsi.Problem(tofsi.load_scene(OPT, TINY))
    meta["identity"]["mesh"]["nx"] += 1
    data["meta"] = np.array(json.dumps(meta))
    with open(out / "checkpoint.npz", "wb") as fh:
        np.savez(fh, **data)
    with pytest.raises(InputError, match="another mesh"):
        check_checkpoint(out / "checkpoint.npz", problem)


def test_resume_without_a_checkpoint_exits_2(cli, tmp_path):
    run = optimize(cli, "--resume", cwd=tmp_path)
    assert run.returncode == 2 and "no checkpoint" in run.stderr and not (tmp_path / "out").exists()
