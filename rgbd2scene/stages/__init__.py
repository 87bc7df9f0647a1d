"""The command stages: mesh folder, scene folder, rendered dataset."""

from rgbd2scene.stages.mesh import write_mesh_folder
from rgbd2scene.stages.render import render_dataset
from rgbd2scene.stages.scene import SceneOptions, build_scene_folder, load_mesh_folder

__all__ = ["SceneOptions", "build_scene_folder", "load_mesh_folder", "render_dataset", "write_mesh_folder"]
