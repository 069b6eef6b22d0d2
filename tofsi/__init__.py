"""tofsi: topology optimization of fluid-structure interaction on structured quads."""

from tofsi.core.version import VERSION as __version__
from tofsi.scene.scene import Scene, load_scene

__all__ = ["Problem", "Scene", "load_scene", "quality", "__version__"]


def __getattr__(name):
    if name == "Problem":                    # imported on first use: it pulls in the physics
        from tofsi.optimization.problem import Problem
        return Problem
    if name == "quality":                    # the public name of tofsi.mesh.quality (skewness, area_change)
        from tofsi.mesh import quality
        return quality
    raise AttributeError(name)
