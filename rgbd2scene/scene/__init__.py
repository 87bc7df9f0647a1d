"""The renderer-independent scene model: stereo rig, camera path, light and objects (no ``bpy``).

The names below load their module on first use (:mod:`rgbd2scene.lazy`): the mesh stage needs only
:mod:`rgbd2scene.scene.folder`."""

from rgbd2scene.lazy import lazy_names

_SUBMODULE_OF = {
    "TissueDetail": "materials", "MATERIALS": "model", "Light": "model", "SceneDescription": "model",
    "SceneObject": "model", "PATH_GENERATORS": "paths", "PATH_KINDS": "paths", "CameraPath": "paths",
    "Track": "paths", "load_path_file": "paths", "look_at": "paths", "make_path": "paths",
    "path_coverage": "paths", "StereoRig": "rig",
}

__all__ = sorted(_SUBMODULE_OF)
__getattr__, __dir__ = lazy_names(__name__, _SUBMODULE_OF)
