"""Shared fixtures: the shipped scenes and small meshes."""

from pathlib import Path

import pytest

import tofsi
from tofsi.channel import build_mesh

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
