"""Ground truth: the map schema, raw render passes -> maps, the occlusion oracle over the scene model (the ray
caster it uses is :mod:`rgbd2scene.geometry.raycast`)."""

from rgbd2scene.groundtruth.passes import MAPS, gt_from_passes, parse_maps, passes_needed
from rgbd2scene.groundtruth.scene_geometry import SceneGeometry, occlusion_maps

__all__ = ["MAPS", "SceneGeometry", "gt_from_passes", "occlusion_maps", "parse_maps", "passes_needed"]
