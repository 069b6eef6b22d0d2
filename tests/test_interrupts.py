"""Issue 36, item 5: snapshots kept across interrupts and --resume; no temporaries left; final
outputs bitwise equal after a kill and a resume.

An interrupt while a design snapshot was written lost it for good (the checkpoint already held
its iteration, and a resume replays without pictures); the ParaView series of a resumed run
listed only the snapshots written after the resume; a kill during the final outputs left
design_final.vtu's sensitivities off by 1e-10 (a resumed run recomputed the gradient); SIGKILL
left temporary files. The references are the uninterrupted run's files, byte for byte, apart
from the wall-clock fields (``time_s``, ``wall_time_s``, the count of evaluations computed).
"""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import scene_path

OPT = str(scene_path("beam_in_channel_optimization"))
RUN = ["--set", "mesh.h_min=0.1", "--set", "mesh.h_max=0.1", "--set", "design.filter_radius=0.15",
       "--set", "design.stage_iterations=2", "--set", "optimizer.max_iter=5", "--set", "optimizer.output_every=2",
       "-q"]
BITWISE = ("design.npy", "final_state.npz", "design_0000.vtu", "design_0002.vtu", "design_0004.vtu",
           "design_final.vtu", "design_series.pvd", "design_0000.png", "design_final.png")
CLOCK = ("time_s", "wall_time_s", "evaluations_computed")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted run (in a process of its own, as the runs compared with it)."""
    out = tmp_path_factory.mktemp("reference") / "out"
    run = subprocess.run([sys.executable, "-m", "tofsi.cli", "optimize", OPT, "--output", str(out), *RUN],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return out


def without_clock(value):
    if isinstance(value, dict):
        return {k: without_clock(v) for k, v in value.items() if k not in CLOCK}
    if isinstance(value, list):
        return [without_clock(v) for v in value]
    return value


def assert_as_uninterrupted(out, reference):
    for name in BITWISE:
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
    for name in ("history.json", "result.json"):
        assert without_clock(json.loads((out / name).read_text())) == \
            without_clock(json.loads((reference / name).read_text())), name
    assert sorted(os.listdir(out)) == sorted(os.listdir(reference))    # no temporary, nothing missing


@pytest.mark.parametrize("where", [0, 2, "final"])
def test_an_interrupt_while_a_snapshot_is_written_loses_nothing_after_resume(where, reference, cli, tmp_path,
                                                                              monkeypatch):
    """Ctrl-C (a KeyboardInterrupt, as SIGTERM) inside the snapshot of iteration ``where``:
    exit 130; --resume writes the snapshot, lists every snapshot in design_series.pvd and ends
    with the uninterrupted run's files."""
    from tofsi.commands.optimize import Pictures
    original = Pictures.__call__

    def interrupted(self, iteration, *args):
        if iteration == where:
            raise KeyboardInterrupt
        return original(self, iteration, *args)
    monkeypatch.setattr(Pictures, "__call__", interrupted)
    first = cli("optimize", OPT, "--output", tmp_path / "out", *RUN)
    assert first.returncode == 130 and "resume with --resume" in first.stderr
    monkeypatch.setattr(Pictures, "__call__", original)
    again = cli("optimize", OPT, "--output", tmp_path / "out", *RUN, "--resume")
    assert again.returncode == 0, again.stderr
    assert_as_uninterrupted(tmp_path / "out", reference)


def test_a_killed_run_resumes_to_the_uninterrupted_files_without_temporaries(reference, tmp_path):
    """SIGKILL mid-run (no clean-up runs): the temporaries it leaves -- here the 0-byte one of
    a VTU being written, as found after such kills, and the reserve -- are gone after --resume,
    whose files are the uninterrupted run's."""
    out = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-m", "tofsi.cli", "optimize", OPT, "--output", str(out), *RUN],
                           stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while not (out / "design_0002.vtu").exists():
        assert run.poll() is None and time.monotonic() - t0 < 120, run.stderr.read() if run.poll() else "slow"
        time.sleep(0.02)
    run.send_signal(signal.SIGKILL)
    run.wait()
    (out / ".design_0004.k1ll3d00.vtu").write_bytes(b"")          # what a kill inside atomic_write leaves
    assert (out / ".tofsi-reserve").exists() and (out / ".tofsi.lock").exists()
    again = subprocess.run([sys.executable, "-m", "tofsi.cli", "optimize", OPT, "--output", str(out), *RUN,
                            "--resume"], capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert not [n for n in os.listdir(out) if n.startswith(".") or (out / n).stat().st_size == 0]
    assert_as_uninterrupted(out, reference)
