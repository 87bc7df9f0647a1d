"""Geometry every stage shares: the camera model, the calibrated stereo pair and its rectified pair, the triangle
mesh type and the ray caster over it (capture, reconstruction, scene, ground truth and files all import it; it
imports none of them). The names below load their module on first use (:mod:`rgbd2scene.lazy`)."""

from rgbd2scene.lazy import lazy_names

_SUBMODULE_OF = {
    "Camera": "camera", "Intrinsics": "camera", "Mesh": "mesh", "vertex_normals": "mesh",
    "Raycaster": "raycast", "raycaster": "raycast", "triangles_in_view": "raycast",
    "Rectification": "rectification", "stereo_rectification": "rectification", "StereoCalibration": "stereo",
}

__all__ = sorted(_SUBMODULE_OF)
__getattr__, __dir__ = lazy_names(__name__, _SUBMODULE_OF)
