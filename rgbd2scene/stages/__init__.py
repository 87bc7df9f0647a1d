"""The command stages: capture input, mesh folder, scene folder, rendered dataset, and the one crossing into
Blender.

The names below load their stage on first use: a command imports only its own stages (``rgbd2scene mesh``
never needs the scene, render or Blender stages, whose imports cost about 0.2 s CPU at every start).
"""

from importlib import import_module

_STAGE_OF = {
    "Task": "blender", "TaskResult": "blender", "run_task": "blender",
    "CaptureOptions": "capture", "LoadedCapture": "capture", "check_inputs": "capture", "load_inputs": "capture",
    "reconstruct_inputs": "capture",
    "scene_record": "mesh", "write_mesh_folder": "mesh",
    "RenderOptions": "render", "render_dataset": "render",
    "SceneOptions": "scene", "build_scene_folder": "scene", "load_mesh_folder": "scene",
}

__all__ = sorted(_STAGE_OF)


def __getattr__(name: str):
    if name not in _STAGE_OF:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_STAGE_OF[name]}"), name)
