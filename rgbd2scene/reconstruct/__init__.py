"""Reconstruction: hole filling, back-projection into a grid mesh, smoothing along the viewing rays."""

from rgbd2scene.reconstruct.fill import FILL_METHODS, FillResult, fill_depth
from rgbd2scene.reconstruct.mesh import grid_mesh
from rgbd2scene.reconstruct.pipeline import MeshOptions, Reconstruction, reconstruct
from rgbd2scene.reconstruct.smooth import smooth_mesh

__all__ = ["FILL_METHODS", "FillResult", "MeshOptions", "Reconstruction", "fill_depth", "grid_mesh",
    "reconstruct", "smooth_mesh"]
