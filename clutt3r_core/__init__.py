"""Clutt3R core: zero-shot 3D instance segmentation of cluttered tabletops.

The algorithm library. It never imports ``clutt3r_viewer``.
"""

from clutt3r_core.errors import Clutt3rError, MissingDependencyError, SceneError, SceneFileError
from clutt3r_core.scene import Camera, GroundTruth, MaskCandidates, ObjectInfo, Scene, View

__version__ = "0.1.0"

__all__ = [
    "Camera",
    "Clutt3rError",
    "GroundTruth",
    "MaskCandidates",
    "MissingDependencyError",
    "ObjectInfo",
    "Scene",
    "SceneError",
    "SceneFileError",
    "View",
]
