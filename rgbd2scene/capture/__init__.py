"""Capture I/O: colour and depth images, camera files and presets (the camera model: :mod:`rgbd2scene.geometry`)."""

from rgbd2scene.capture.camera import PRESET_DEPTH_SCALE, PRESETS, load_camera, load_camera_json, preset
from rgbd2scene.capture.readers import Capture, load_capture, read_depth, read_rgb

__all__ = ["Capture", "PRESETS", "PRESET_DEPTH_SCALE", "load_camera", "load_camera_json", "load_capture", "preset",
    "read_depth", "read_rgb"]
