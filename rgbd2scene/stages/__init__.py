"""The command stages: capture input, mesh folder, scene folder, rendered dataset, and the one crossing into
Blender.

The names below load their stage on first use: a command imports only its own stages (``rgbd2scene mesh``
never needs the scene, render or Blender stages, whose imports cost about 0.2 s CPU at every start;
:mod:`rgbd2scene.lazy`).
"""

from rgbd2scene.lazy import lazy_names

_STAGE_OF = {
    "Task": "blender", "TaskResult": "blender", "run_task": "blender",
    "CaptureOptions": "capture", "LoadedCapture": "capture", "check_inputs": "capture", "load_inputs": "capture",
    "reconstruct_inputs": "capture",
    "reconstruct_mesh_folder": "mesh", "scene_record": "mesh", "write_mesh_folder": "mesh",
    "RenderOptions": "render", "render_dataset": "render",
    "SceneOptions": "scene", "build_scene_folder": "scene", "load_mesh_folder": "scene",
}

__all__ = sorted(_STAGE_OF)
__getattr__, __dir__ = lazy_names(__name__, _STAGE_OF)
