"""The command stages: capture input, mesh folder, scene folder, rendered dataset, and the one crossing into
Blender."""

from rgbd2scene.stages.blender import Task, TaskResult, run_task
from rgbd2scene.stages.capture import CaptureOptions, LoadedCapture, check_inputs, load_inputs, reconstruct_inputs
from rgbd2scene.stages.mesh import scene_record, write_mesh_folder
from rgbd2scene.stages.render import RenderOptions, render_dataset
from rgbd2scene.stages.scene import SceneOptions, build_scene_folder, load_mesh_folder

__all__ = ["CaptureOptions", "LoadedCapture", "RenderOptions", "SceneOptions", "Task", "TaskResult",
           "build_scene_folder", "check_inputs", "load_inputs", "load_mesh_folder", "reconstruct_inputs",
           "render_dataset", "run_task", "scene_record", "write_mesh_folder"]
