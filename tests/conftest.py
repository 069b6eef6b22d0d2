"""Shared fixtures: the shipped scenes and small meshes."""

from pathlib import Path

import pytest

import tofsi
from tofsi.mesh.channel import build_mesh

SCENES = Path(__file__).resolve().parents[1] / "examples" / "scenes"
MOTION_SCENES = ["beam_in_channel", "foil_in_channel"]
ALL_SCENES = sorted(p.stem for p in SCENES.glob("*.toml"))


def scene_path(name: str) -> Path:
    return SCENES / f"{name}.toml"


def load(name: str, *overrides):
    return tofsi.load_scene(scene_path(name), list(overrides))


@pytest.fixture(params=ALL_SCENES)
def shipped_scene(request):
    return load(request.param)


@pytest.fixture(params=ALL_SCENES)
def shipped_mesh(request):
    scene = load(request.param)
    return scene, build_mesh(scene.geometry, scene.mesh)


@pytest.fixture
def cli(monkeypatch, capsys):
    """Run ``tofsi ARGS`` in this process (no interpreter start-up): ``cli(*args, cwd=DIR)``
    returns an object with ``returncode``, ``stdout`` and ``stderr`` like ``subprocess.run``.
    ``stderr`` holds the log lines as the command line writes them (under pytest the root
    logger has handlers already, so the ``logging.basicConfig`` of ``tofsi.cli`` adds none:
    this fixture adds the same format for the run). Tests where the process matters use a
    subprocess: signals, the installed entry point, resource limits, the environment, and
    Python warnings (pytest records those instead of printing them)."""
    import logging
    import sys
    import types

    from tofsi.cli import LOGGERS, main

    def run(*args, cwd=None):
        if cwd is not None:
            monkeypatch.chdir(cwd)
        capsys.readouterr()
        handler = logging.StreamHandler(sys.stderr)                 # capsys's stream, now
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))   # as tofsi.cli's
        logging.getLogger().addHandler(handler)
        try:
            status = main([str(a) for a in args])
        finally:
            logging.getLogger().removeHandler(handler)
        out, err = capsys.readouterr()
        return types.SimpleNamespace(returncode=status, stdout=out, stderr=err)
    yield run
    for name in LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET)


def cyclic_garbage(action):
    """``(result, counts)``: ``action()``'s result, and the type names (with counts) of what it
    left that only Python's cyclic garbage collector would free -- collected with the collector
    off, so nothing is freed before it is counted."""
    import collections
    import gc
    gc.collect()
    gc.disable()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        result = action()
        gc.collect()
        return result, collections.Counter(type(o).__name__ for o in gc.garbage)
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()
