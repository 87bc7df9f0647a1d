"""The scene stage: a reconstruction (or a mesh folder) + rig + path + light -> SCENE folder with scene.blend.

The Blender work itself is in ``render.blender_scene``; this module decides what to build and records it
in ``scene.json`` (written last: a scene folder with a scene.json is complete).
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rgbd2scene.capture.camera import Intrinsics
from rgbd2scene.errors import UserError
from rgbd2scene.files.atomic import write_json
from rgbd2scene.files.images import read_image
from rgbd2scene.files.meshio import read_ply
from rgbd2scene.groundtruth.raycast import raycaster
from rgbd2scene.scene.materials import TissueDetail
from rgbd2scene.scene.model import MATERIALS, Light, SceneDescription, SceneObject
from rgbd2scene.scene.path import DEFAULT_STANDOFF, CameraPath, load_path_file, make_path, path_coverage
from rgbd2scene.scene.rig import DEFAULT_BASELINE, DEFAULT_FOV_X_DEG, DEFAULT_SIZE, StereoRig
from rgbd2scene.stages.mesh import TEXTURE_ORIGINAL


@dataclass
class SceneOptions:
    """Everything the user chooses about the scene (defaults: a da Vinci-class scope scanning tissue)."""

    size: tuple[int, int] = DEFAULT_SIZE
    fov_x_deg: float = DEFAULT_FOV_X_DEG
    intrinsics: Intrinsics | None = None  # exact fx, fy, cx, cy (overrides size and fov)
    baseline: float = DEFAULT_BASELINE
    path: str = "scan"
    path_file: str | None = None
    frames: int = 60
    fps: float = 30.0
    standoff: float = DEFAULT_STANDOFF
    seed: int = 0
    material: str = "wet_tissue"
    tissue_detail: TissueDetail = field(default_factory=TissueDetail)  # of the wet_tissue material
    light: str = "spot"
    light_power_w: float = 0.05

    def rig(self) -> StereoRig:
        if self.baseline <= 0 or self.baseline > 0.1:
            raise UserError(f"--baseline: {self.baseline} m is not a plausible endoscope baseline (0-0.1 m)")
        if self.intrinsics is not None:
            intr = self.intrinsics
        else:
            intr = Intrinsics.from_fov(*self.size, self.fov_x_deg)
            intr.check("--fov/--size")
        return StereoRig(intr, self.baseline)


def make_description(vertices: np.ndarray, triangles: np.ndarray, options: SceneOptions, rc=None) -> SceneDescription:
    """Rig, path (generated over the mesh or read from a path file), light and material.

    ``rc`` is a ready ``raycast.Raycaster`` of the mesh (built here if not given).
    """
    if options.material not in MATERIALS:
        raise UserError(f"--material: unknown material {options.material!r}; choose one of {', '.join(MATERIALS)}")
    if options.light not in ("spot", "point"):
        raise UserError(f"--light: must be spot or point, got {options.light!r}")
    rig = options.rig()
    if options.path_file:
        path: CameraPath = load_path_file(options.path_file)
    else:
        path = make_path(options.path, vertices, triangles, rig, frames=options.frames, fps=options.fps,
                         seed=options.seed, standoff=options.standoff, rc=rc)
    light = Light(kind=options.light, power_w=options.light_power_w)
    detail = options.tissue_detail
    if options.material != "wet_tissue":  # only the wet-tissue material has it: record what is built
        detail = replace(detail, enabled=False)
    return SceneDescription(rig, path, light, options.material, mesh_file="mesh.ply",
                            texture_file="mesh_texture.png", objects=[SceneObject(1, "tissue")],
                            tissue_detail=detail)


def build_scene_folder(out_dir: Path, mesh, record: dict, options: SceneOptions) -> dict:
    """Build SCENE/scene.blend for ``mesh`` (already written to out_dir) and write scene.json last."""
    from render.scene_builder import build_scene  # bpy lives in render/

    t0 = time.perf_counter()
    rc = raycaster(mesh.vertices, mesh.triangles)
    desc = make_description(mesh.vertices, mesh.triangles, options, rc=rc)
    coverage = path_coverage(mesh.vertices, mesh.triangles, desc.rig, desc.path, scale=0.5, rc=rc)
    timings = {"path_s": time.perf_counter() - t0}
    t0 = time.perf_counter()
    build_scene(desc, mesh, out_dir / "scene.blend")
    timings["blend_s"] = time.perf_counter() - t0
    record = dict(record)
    record["scene"] = desc.to_dict()
    record["scene_options"] = {k: (list(v) if isinstance(v, tuple) else v.to_dict() if hasattr(v, "to_dict")
                                   else v) for k, v in options.__dict__.items()}
    record["coverage"] = {"min": float(coverage.min()), "mean": float(coverage.mean()),
                          "per_frame_left_right": coverage.round(4).tolist(), "check_scale": 0.5}
    record["blend"] = "scene.blend"
    record.setdefault("timings", {}).update(timings)
    write_json(out_dir / "scene.json", record)
    return record


def load_mesh_folder(mesh_dir: str | Path, out_dir: Path):
    """Mesh (with UVs and texture) and scene.json record of a folder made by ``rgbd2scene mesh``.

    When ``out_dir`` differs, the folder's files are copied there so the scene folder stands alone.
    """

    src = Path(mesh_dir)
    record_path = src / "scene.json"
    if not record_path.is_file() or not (src / "mesh.ply").is_file():
        raise UserError(f"{src}: not a mesh folder made by 'rgbd2scene mesh' (needs scene.json and mesh.ply)")
    try:
        record = json.loads(record_path.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"{record_path}: not valid JSON ({exc})") from None
    # from here on out_dir is a scene being built: it must not look complete until scene.json is rewritten
    (out_dir / "scene.json").unlink(missing_ok=True)
    mesh = read_ply(src / "mesh.ply")
    texture_path = src / "mesh_texture.png"
    if texture_path.is_file():
        mesh.texture = read_image(texture_path)
        if mesh.texture is None:
            raise UserError(f"{texture_path}: not a readable texture image")
    if src.resolve() != out_dir.resolve():
        for name in ("mesh.ply", "depth_filled.npy", "mesh.obj", "mesh.mtl", "mesh_texture.png", TEXTURE_ORIGINAL,
                     "overview.png"):
            if (src / name).is_file():
                shutil.copy2(src / name, out_dir / name)
    record.pop("scene", None)
    return mesh, record
