"""Capture I/O: colour and depth images, intrinsics and camera presets."""

from rgbd2scene.capture.camera import PRESET_DEPTH_SCALE, PRESETS, Intrinsics, load_camera_json, preset
from rgbd2scene.capture.readers import Capture, load_capture, read_depth, read_rgb

__all__ = ["Capture", "Intrinsics", "PRESETS", "PRESET_DEPTH_SCALE", "load_camera_json", "load_capture", "preset",
    "read_depth", "read_rgb"]
