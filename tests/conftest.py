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
    Log lines go to pytest's capture, not to ``stderr``: tests of logging use a subprocess."""
    import logging
    import types

    from tofsi.cli import LOGGERS, main

    def run(*args, cwd=None):
        if cwd is not None:
            monkeypatch.chdir(cwd)
        capsys.readouterr()
        status = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return types.SimpleNamespace(returncode=status, stdout=out, stderr=err)
    yield run
    for name in LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET)
