"""The command stages: mesh folder, scene folder, rendered dataset, and the one crossing into Blender."""

from rgbd2scene.stages.blender import Task, TaskResult, run_task
from rgbd2scene.stages.mesh import scene_record, write_mesh_folder
from rgbd2scene.stages.render import RenderOptions, render_dataset
from rgbd2scene.stages.scene import SceneOptions, build_scene_folder, load_mesh_folder

__all__ = ["RenderOptions", "SceneOptions", "Task", "TaskResult", "build_scene_folder", "load_mesh_folder",
           "render_dataset", "run_task", "scene_record", "write_mesh_folder"]
