"""Ground truth: the map schema, raw render passes -> maps, and the ray-casting oracle."""

from rgbd2scene.groundtruth.passes import MAPS, gt_from_passes, parse_maps, passes_needed
from rgbd2scene.groundtruth.raycast import Raycaster, raycaster
from rgbd2scene.groundtruth.scene_geometry import SceneGeometry, occlusion_maps

__all__ = ["MAPS", "Raycaster", "SceneGeometry", "gt_from_passes", "occlusion_maps", "parse_maps", "passes_needed",
           "raycaster"]
