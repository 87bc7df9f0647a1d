"""The wet-tissue micro-structure: settings, recorded in scene.json, a look that keeps the capture's mean colour,
and no trace of it in any ground-truth map (byte-identical with it on or off).

Renders are tiny (64x32 datasets of 3 frames; 192x96 unlit albedo images of a plane).
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from rgbd2scene import conventions as cv
from rgbd2scene.dataset import layout as ds
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.scene.materials import MAX_MOTTLE_STRENGTH, TissueDetail
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object
from rgbd2scene.scene.paths import CameraPath, look_at
from rgbd2scene.scene.rig import StereoRig

GT_MAPS = ("depth", "disparity", "normals", "flow_forward", "flow_backward", "segmentation")


# ================================================================ settings (no Blender)

def _description(detail: TissueDetail, intr: Intrinsics, poses) -> SceneDescription:
    rig = StereoRig.parallel(intr, 0.005, clip_start=0.001, clip_end=2.0)
    return SceneDescription(rig, CameraPath(np.asarray(poses, float).reshape(-1, 4, 4), fps=25.0, kind="test"),
                            Light(power_w=0.05), [tissue_object("wet_tissue", detail=detail)])


def _detail_record(scene: dict) -> dict | None:
    """The tissue's detail in a scene.json ``scene`` record."""
    return scene["objects"][0]["parts"][0]["material"]["detail"]


def test_detail_settings_round_trip_through_the_description():
    detail = TissueDetail(seed=7, scale_m=0.001, bump_height_m=0.0001)
    desc = _description(detail, Intrinsics.from_fov(64, 32, 70.0), [np.eye(4)])
    record = json.loads(json.dumps(desc.to_dict()))
    assert _detail_record(record) == detail.to_dict() and _detail_record(record)["enabled"] is True
    assert SceneDescription.from_dict(record).objects[0].parts[0].material.detail == detail
    record["objects"][0]["parts"][0]["material"]["detail"] = None  # a scene without it
    assert SceneDescription.from_dict(record).objects[0].parts[0].material.detail is None
    assert TissueDetail.from_dict({"seed": 3}) == TissueDetail(seed=3)


@pytest.mark.parametrize("bad, message", [({"scale_m": 0.0}, "scale_m"), ({"vessel_strength": 1.5}, "vessel"),
                                          ({"mottle_strength": MAX_MOTTLE_STRENGTH + 0.01}, "mottle"),
                                          ({"bump_height_m": -1e-4}, "bump")])
def test_bad_detail_settings(bad, message):
    with pytest.raises(ValueError, match=message):
        TissueDetail(**bad)


def test_unknown_detail_setting():
    with pytest.raises(ValueError, match="unknown setting"):
        TissueDetail.from_dict({"sparkle": 1.0})


# ================================================================ Blender

bpy = pytest.importorskip("bpy")
pytest.importorskip("OpenEXR")

from render.scene_builder import build_scene  # noqa: E402
from rgbd2scene.cli import main  # noqa: E402
from rgbd2scene.files.images import write_image  # noqa: E402
from rgbd2scene.stages.blender import BuildScene, Task, run_task  # noqa: E402
from rgbd2scene.stages.render import render_dataset  # noqa: E402
from tests.conftest import render_base_colour, write_scene_files  # noqa: E402

TISSUE_RGB = (200, 110, 100)


def _srgb_to_linear(rgb) -> np.ndarray:
    c = np.asarray(rgb, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _plane(half: float = 0.04, z: float = 0.05) -> SimpleNamespace:
    """A flat square facing the camera at the origin, one colour."""
    verts = np.array([(-half, -half, z), (half, -half, z), (half, half, z), (-half, half, z)])
    return SimpleNamespace(vertices=verts, triangles=np.array([[0, 2, 1], [0, 3, 2]], np.int32),
                           uvs=np.full((4, 2), 0.5, np.float32), vertex_colors=np.full((4, 3), 128, np.uint8),
                           texture=np.full((2, 2, 3), TISSUE_RGB, np.uint8))


def _albedo(detail: TissueDetail, tmp_path) -> np.ndarray:
    """Linear RGB base colour the wet-tissue material computes on a plane filling the view (192x96, left eye)."""
    intr = Intrinsics.from_fov(192, 96, 70.0)  # 0.4 mm pixels: most of the mottling's octaves resolved
    desc = _description(detail, intr, [np.eye(4)])
    folder = tmp_path / "albedo_scene"
    build_scene(desc, write_scene_files(folder, _plane(), desc))
    return render_base_colour(bpy, "wet_tissue", tmp_path / "albedo.exr")


def test_detail_keeps_the_mean_colour_and_adds_the_asked_contrast(tmp_path):
    base = _srgb_to_linear(TISSUE_RGB)
    plain = _albedo(TissueDetail(enabled=False), tmp_path) / base
    assert np.allclose(plain, 1.0, atol=1e-3)  # off: the texture's colour everywhere

    detail = _albedo(TissueDetail(), tmp_path) / base
    mean = detail.reshape(-1, 3).mean(axis=0)
    print(f"default detail: albedo mean / texture {np.round(mean, 4)}, std {np.round(detail.std(axis=(0, 1)), 3)}")
    assert np.all(np.abs(mean - 1.0) < 0.03)  # the capture's colour at low spatial frequencies
    assert detail.std(axis=(0, 1)).min() > 0.04  # and visible structure around it
    # vessels (0.1 mm wide, a fraction of a 0.4 mm pixel here): darker, more in green than in red (dark red)
    assert detail[..., 1].min() < 0.75 and (detail[..., 1] - detail[..., 0]).min() < -0.1

    mottle = _albedo(TissueDetail(vessel_strength=0.0, mottle_strength=0.1), tmp_path) / base
    print(f"mottling 0.1: mean {mottle.mean():.4f}, std {mottle.std():.4f}")
    assert abs(mottle.mean() - 1.0) < 0.02 and 0.08 < mottle.std() < 0.12

    other = _albedo(TissueDetail(seed=1), tmp_path) / base
    assert abs(np.corrcoef(other[..., 1].ravel(), detail[..., 1].ravel())[0, 1]) < 0.5  # another tissue


def _relief_mesh(intr: Intrinsics) -> SimpleNamespace:
    """A bumpy grid surface about 5 cm in front of the capture camera, textured."""
    h, w = 24, 40
    u, v = cv.pixel_grid(h, w)
    depth = 0.05 + 0.002 * np.sin(u / 4.0) * np.cos(v / 3.0) + 0.0002 * u
    K = intr.resized(w, h).K
    idx = np.arange(h * w).reshape(h, w)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    texture = np.random.default_rng(4).integers(90, 220, (h, w, 3), dtype=np.uint8)
    uvs = np.stack([(u + 0.5) / w, 1.0 - (v + 0.5) / h], -1).reshape(-1, 2).astype(np.float32)
    return SimpleNamespace(vertices=cv.backproject(depth, K).reshape(-1, 3), triangles=tris.astype(np.int32),
                           uvs=uvs, vertex_colors=texture.reshape(-1, 3), texture=texture)


def _scene_folder(folder, detail: TissueDetail):
    intr = Intrinsics.from_fov(64, 32, 60.0)
    poses = [look_at([0.001 * k, 0.0005 * k, 0.01], [0.0015 * k, 0.0, 0.05]) for k in range(3)]
    desc = _description(detail, intr, poses)
    write_scene_files(folder, _relief_mesh(intr), desc)
    run_task(Task(BuildScene(str(folder), desc.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": desc.to_dict()}))
    return folder


def test_ground_truth_is_byte_identical_with_detail_on_or_off(tmp_path):
    datasets = {}
    for name, detail in (("on", TissueDetail()), ("off", TissueDetail(enabled=False))):
        scene = _scene_folder(tmp_path / f"scene_{name}", detail)
        datasets[name] = tmp_path / f"data_{name}"
        render_dataset(scene, datasets[name], samples=4, denoise="none", progress=False)
    rgb_change = []
    for frame in range(3):
        for eye in ds.EYES:
            rgb_on, gt_on = ds.read_frame(datasets["on"], eye, frame)
            rgb_off, gt_off = ds.read_frame(datasets["off"], eye, frame)
            assert set(gt_on) == set(gt_off)
            for key in GT_MAPS:
                assert gt_on[key].dtype == gt_off[key].dtype and gt_on[key].shape == gt_off[key].shape, key
                assert gt_on[key].tobytes() == gt_off[key].tobytes(), (frame, eye, key)
            assert np.isfinite(gt_on["depth"]).mean() > 0.9 and np.isfinite(gt_on["normals"]).all(axis=-1).mean() > 0.9
            rgb_change.append(np.abs(rgb_on.astype(int) - rgb_off.astype(int)).mean())
    print(f"mean |RGB on - off| per image: {np.round(rgb_change, 1)} / 255")
    # the detail is there: every image changes (2.9-3.4 levels with the flat vignetting default of session 8; two
    # renders of one scene give the same bytes, so any change is the detail's)
    assert min(rgb_change) > 2.0


def test_scene_command_records_and_builds_the_detail(tmp_path):
    h, w = 48, 64
    intr = {"width": w, "height": h, "fx": 64.0, "fy": 64.0, "cx": (w - 1) / 2, "cy": (h - 1) / 2, "depth_scale": 1000}
    (tmp_path / "camera.json").write_text(json.dumps(intr))
    u, _ = cv.pixel_grid(h, w)
    write_image(tmp_path / "depth.png", (300 + u).astype(np.uint16))  # millimetres: a slanted plane
    write_image(tmp_path / "rgb.png", np.full((h, w, 3), TISSUE_RGB, np.uint8))
    capture = ["--rgb", str(tmp_path / "rgb.png"), "--depth", str(tmp_path / "depth.png"),
               "--camera", str(tmp_path / "camera.json"), "--no-overview", "--frames", "2", "--standoff", "0.1"]
    for switch, seed in (("on", 5), ("off", 0)):
        out = tmp_path / switch
        assert main(["scene", *capture, "--tissue-detail", switch, "--seed", str(seed), "-o", str(out)]) == 0
        record = json.loads((out / "scene.json").read_text())
        expected = TissueDetail(enabled=switch == "on", seed=seed).to_dict()
        assert _detail_record(record["scene"]) == expected
        assert record["scene_options"]["tissue_detail"] == switch
        bpy.ops.wm.open_mainfile(filepath=str(out / "scene.blend"))
        assert _detail_record(json.loads(bpy.context.scene["rgbd2scene"])) == expected
        kinds = {n.bl_idname for n in bpy.data.materials["wet_tissue"].node_tree.nodes}
        assert ("ShaderNodeBump" in kinds) == (switch == "on")
        # "on" bakes the detail into textures read through their own UV map: no noise is left to evaluate
        assert ("ShaderNodeUVMap" in kinds) == (switch == "on") and "ShaderNodeTexNoise" not in kinds
    # the unlit material is the texture alone: no detail is built, and the record says so
    out = tmp_path / "unlit"
    assert main(["scene", *capture, "--material", "as_captured", "-o", str(out)]) == 0
    assert _detail_record(json.loads((out / "scene.json").read_text())["scene"])["enabled"] is False
