"""tofsi: topology optimization of fluid-structure interaction on structured quads."""

from tofsi.scene import Scene, load_scene

__version__ = "0.1.0"
__all__ = ["Scene", "load_scene", "__version__"]
