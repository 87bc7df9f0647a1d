"""Everything that touches Blender (``bpy``): building the stereo-endoscope scene and rendering it.

The numpy core (``rgbd2scene``) never imports ``bpy``; import this package only where Blender is needed.
Importing the package itself does not import ``bpy`` (its names load on first use): the worker
(``python -m render.worker``) starts a render's ground-truth child before it imports Blender.
"""

__all__ = ["build_scene", "set_intrinsics"]


def __getattr__(name: str):
    if name in __all__:
        from render import scene_builder

        return getattr(scene_builder, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
