"""Geometry every stage shares: the camera model, the calibrated stereo pair and its rectified pair, the triangle
mesh type and the ray caster over it (capture, reconstruction, scene, ground truth and files all import it; it
imports none of them)."""

from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.mesh import Mesh, vertex_normals
from rgbd2scene.geometry.raycast import Raycaster, raycaster, triangles_in_view
from rgbd2scene.geometry.rectification import Rectification, stereo_rectification
from rgbd2scene.geometry.stereo import StereoCalibration

__all__ = ["Camera", "Intrinsics", "Mesh", "Raycaster", "Rectification", "StereoCalibration", "raycaster",
           "stereo_rectification", "triangles_in_view", "vertex_normals"]
