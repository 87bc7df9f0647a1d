"""Everything that touches Blender (``bpy``): building the stereo-endoscope scene and rendering it.

The numpy core (``rgbd2scene``) never imports ``bpy``; import this package only where Blender is needed.
"""

from render.scene_builder import build_scene, set_intrinsics

__all__ = ["build_scene", "set_intrinsics"]
