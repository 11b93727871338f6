"""The active-filament plug-in: scene -> effects -> numba kernels -> Model.

``FilamentModel(scene)`` builds the model from a :class:`Scene` (or a
``[scene]`` table / TOML path, see :func:`load_scene`).
"""

from .model import FilamentModel
from .scene import Scene, load_scene

__all__ = ["FilamentModel", "Scene", "load_scene"]
