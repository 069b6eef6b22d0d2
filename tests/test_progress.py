"""Progress, verbosity, SIGTERM, and studies that keep their finished and failed points."""

import csv
import fcntl
import json
import os
import pty
import signal
import struct
import subprocess
import sys
import termios
import time

import pytest

import tofsi
from tofsi.optimization.optimize import Optimizer
from tofsi.runs.output import read_csv

from conftest import scene_path

FOIL = str(scene_path("foil_in_channel"))
OPT = str(scene_path("beam_in_channel_optimization"))
SMALL_OPT = ["mesh.h_min=0.1", "mesh.h_max=0.1"]
TINY = SMALL_OPT + ["design.filter_radius=0.25", "design.stage_iterations=6", "optimizer.max_iter=40"]


def command(name, scene, overrides, *args):
    return [sys.executable, "-m", "tofsi.cli", name, scene,
            *[a for o in overrides for a in ("--set", o)], *map(str, args)]


def test_a_long_step_shows_a_line_when_stderr_is_not_a_terminal(tmp_path):
    run = subprocess.run(command("solve", OPT, SMALL_OPT, "--output", "o"), capture_output=True,
                         text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "solving flow, structure on 210 quads ..." in run.stderr.splitlines()
    quiet = subprocess.run(command("solve", OPT, SMALL_OPT, "--output", "q", "-q"), capture_output=True,
                           text=True, cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == "" and quiet.stdout == ""


def test_a_long_step_shows_a_bar_with_the_elapsed_time_on_a_terminal(tmp_path):
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))   # 120 columns
    proc = subprocess.Popen(command("solve", OPT, SMALL_OPT, "--output", "o"), stdout=subprocess.DEVNULL,
                            stderr=slave, cwd=tmp_path)
    os.close(slave)
    seen = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:                                  # the child closed the terminal
            break
        if not chunk:
            break
        seen += chunk
    assert proc.wait() == 0
    os.close(master)
    text = seen.decode(errors="replace")
    assert "solving flow, structure on 210 quads [00:0" in text         # tqdm's elapsed time
    assert "solving flow, structure on 210 quads ..." not in text       # no plain line there


def test_verbose_shows_newton_and_linear_solver_iterations_without_third_party_noise(tmp_path):
    run = subprocess.run(command("solve", OPT, SMALL_OPT, "--output", "o", "-vv"), capture_output=True,
                         text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    logs = [ln for ln in run.stderr.splitlines() if ln.split(" ", 1)[0] in ("DEBUG", "INFO", "WARNING")]
    newton = [ln for ln in logs if "flow Newton" in ln]
    assert len(newton) >= 3 and all("|R| = " in ln for ln in newton)
    assert any("GMRES" in ln or "factorization" in ln for ln in logs)
    assert all(ln.split(" ")[1].split(".")[0] in ("tofsi", "movers", "adjoint") for ln in logs)
    plain = subprocess.run(command("solve", OPT, SMALL_OPT, "--output", "p"), capture_output=True,
                           text=True, cwd=tmp_path)
    assert "flow Newton" not in plain.stderr


def wait_for(path, proc, timeout=120.0):
    t0 = time.time()
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.time() - t0 < timeout
        time.sleep(0.05)


def test_sigterm_checkpoints_and_exits_143_like_ctrl_c(tmp_path):
    proc = subprocess.Popen(command("optimize", OPT, TINY, "--output", "o"), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    wait_for(tmp_path / "o" / "history.json", proc)
    while len(json.loads((tmp_path / "o" / "history.json").read_text() or "[]")) < 3:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143
    assert err.strip().splitlines() == ["tofsi: terminated (resume with --resume)"]
    record = json.loads((tmp_path / "o" / "run.json").read_text())
    assert record["status"] == "terminated" and record["stop_reason"] == "interrupted"
    resumed = subprocess.run(command("optimize", OPT, TINY, "--output", "o", "--resume"),
                             capture_output=True, text=True, cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    record = json.loads((tmp_path / "o" / "run.json").read_text())
    assert record["resumed_from"]["exit_status"] == 143 and record["exit_status"] == 0
    full = Optimizer(tofsi.Problem(tofsi.load_scene(OPT, TINY)), tmp_path / "full")
    full.run()
    history = json.loads((tmp_path / "o" / "history.json").read_text())
    assert [(h["objective"], h["volume"], h["change"]) for h in history] == \
        [(h.objective, h.volume, h.change) for h in full.history]                  # bit for bit


@pytest.mark.parametrize("jobs", [1, 2])
def test_an_interrupted_study_keeps_its_finished_points(jobs, tmp_path):
    proc = subprocess.Popen(command("study", FOIL, ["mesh.h_min=0.05", "mesh.h_max=0.1", "mover.name=yeoh"],
                                    "--sweep", "mover.layers[0]=1:40:1", "--jobs", jobs, "--output", "o"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    for line in proc.stderr:                            # a line per finished point
        if line.startswith("study: 2/40"):
            break
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 143
    rows = read_csv(tmp_path / "o" / "study.csv")
    assert 2 <= len(rows) < 40 and f"{len(rows)} of 40 points written" in out
    assert [r["mover.layers[0]"] for r in rows] == [float(k) for k in range(1, len(rows) + 1)]
    assert all(r["status"] == "ok" for r in rows)


def test_failed_points_are_marked_in_the_csv_and_the_plot_and_counted(tmp_path, monkeypatch):
    run = subprocess.run(command("study", FOIL, ["mesh.h_min=0.05", "mesh.h_max=0.1", "mover.name=spring",
                                                 "deformation.mode=rotation", "deformation.rotation_deg=45"],
                                 "--sweep", "mover.spring.increments=1,2,10", "--output", "o", "--json"),
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["failed"] == 1 and "1 of 3 points failed" in run.stderr
    rows = list(csv.DictReader(open(tmp_path / "o" / "study.csv")))
    assert [r["status"] for r in rows] == ["failed", "ok", "ok"]
    assert rows[0]["converged"] == "False" and float(rows[0]["n_inverted"]) > 0

    import tofsi.runs.plotting as plotting
    figures = []
    monkeypatch.setattr(plotting, "save", lambda fig, path: figures.append(fig))
    plotting.plot_sweep(tmp_path / "s.png", read_csv(tmp_path / "o" / "study.csv"),
                        ["mover.spring.increments"])
    crosses = [ln for ax in figures[0].axes for ln in ax.get_lines() if ln.get_marker() == "x"]
    assert len(crosses) == 4 and all(list(ln.get_xdata()) == [1.0] for ln in crosses)
    assert crosses[0].get_label() == "failed"
