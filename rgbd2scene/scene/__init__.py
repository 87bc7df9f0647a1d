"""The renderer-independent scene model: stereo rig, camera path, light and objects (no ``bpy``)."""

from rgbd2scene.scene.materials import TissueDetail
from rgbd2scene.scene.model import MATERIALS, Light, SceneDescription, SceneObject
from rgbd2scene.scene.paths import (
    PATH_GENERATORS,
    PATH_KINDS,
    CameraPath,
    Track,
    load_path_file,
    look_at,
    make_path,
    path_coverage,
)
from rgbd2scene.scene.rig import StereoRig

__all__ = ["CameraPath", "Light", "MATERIALS", "PATH_GENERATORS", "PATH_KINDS", "SceneDescription", "SceneObject",
           "StereoRig", "TissueDetail", "Track", "load_path_file", "look_at", "make_path", "path_coverage"]
