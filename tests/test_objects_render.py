"""Objects rendered through the one Blender entry point: the instrument's parts and a moving mesh.

Tiny scenes (a plane of tissue, 64x32, 3 frames, 1 sample, no denoiser) built from the scene model with
:func:`~rgbd2scene.scene.objects.assemble.add_objects` and rendered by ``render_dataset``; every answer is
checked against an independent computation: a ray cast of each part's own mesh (from ``SCENE/objects``) at
its pose, and the flow a known rigid motion implies.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bpy")
pytest.importorskip("OpenEXR")

from rgbd2scene import conventions as cv  # noqa: E402
from rgbd2scene.dataset import layout as ds  # noqa: E402
from rgbd2scene.files.meshio import read_ply  # noqa: E402
from rgbd2scene.geometry.camera import Intrinsics  # noqa: E402
from rgbd2scene.geometry.raycast import raycaster  # noqa: E402
from rgbd2scene.scene.config import parse_scene_config  # noqa: E402
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object  # noqa: E402
from rgbd2scene.scene.objects.assemble import Tissue, add_objects  # noqa: E402
from rgbd2scene.scene.paths import CameraPath  # noqa: E402
from rgbd2scene.scene.rig import StereoRig  # noqa: E402
from rgbd2scene.stages.blender import BuildScene, Task, run_task  # noqa: E402
from rgbd2scene.stages.render import render_dataset  # noqa: E402
from tests.conftest import write_scene_files  # noqa: E402

INTR = Intrinsics(64, 32, 40.0, 40.0, 31.5, 15.5)
BASELINE = 0.005
PLANE_Z = 0.05
FRAMES = 3
STEP = 0.001  # the moving box: 1 mm per frame along +x


def _plane(z: float = PLANE_Z, half: float = 0.3):
    from types import SimpleNamespace

    corners = [(-half, -half, z), (half, -half, z), (half, half, z), (-half, half, z)]
    # counter-clockwise seen from the camera at the origin: normals face it
    return SimpleNamespace(vertices=np.asarray(corners, float), triangles=np.array([[0, 2, 1], [0, 3, 2]], np.int32),
                           uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
                           vertex_colors=np.full((4, 3), 150, np.uint8), texture=np.full((4, 4, 3), 150, np.uint8))


def _build(folder: Path, config: dict, camera_poses: np.ndarray) -> tuple[Path, SceneDescription]:
    """Scene folder: the plane as tissue, the configuration's objects, the camera on ``camera_poses``."""
    rig = StereoRig.parallel(INTR, BASELINE, clip_start=0.001, clip_end=2.0)
    plane = _plane()
    desc = SceneDescription(rig, CameraPath(camera_poses, fps=10.0, kind="test"), Light(),
                            [tissue_object("as_captured")])
    write_scene_files(folder, plane, desc)
    tissue = Tissue(plane.vertices, plane.triangles, raycaster(plane.vertices, plane.triangles))
    desc, record = add_objects(desc, tissue, parse_scene_config(config, folder), folder, seed=1)
    run_task(Task(BuildScene(str(folder), desc.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": desc.to_dict(), "objects": record}))
    return folder, desc


def _camera_poses(step=(0.0, 0.0, 0.0)) -> np.ndarray:
    poses = np.tile(np.eye(4), (FRAMES, 1, 1))
    poses[:, :3, 3] = np.arange(FRAMES)[:, None] * np.asarray(step)
    return poses


def _posed_raycasters(folder: Path, desc: SceneDescription, frame: int) -> dict[int, object]:
    """Instance id -> ray caster of that part's own geometry file placed at its pose of ``frame``."""
    out = {}
    for _, part in desc.parts():
        mesh = read_ply(folder / part.geometry)
        out[part.id] = raycaster(cv.transform_points(part.pose_at(frame), mesh.vertices), mesh.triangles)
    return out


@pytest.fixture(scope="module")
def instrument_dataset(tmp_path_factory):
    folder = tmp_path_factory.mktemp("instrument_scene")
    config = {"objects": [{"kind": "instrument", "shaft_diameter": 0.005,
                           "motion": {"entry_fraction": 0.0, "trocar_azimuth_deg": 0.0, "hover": 0.006}}]}
    scene, desc = _build(folder, config, _camera_poses((0.0005, 0.0, 0.0)))
    out = tmp_path_factory.mktemp("instrument_data") / "ds"
    render_dataset(scene, out, samples=1, denoise="none", progress=False)
    return scene, desc, out


def test_instrument_parts_have_distinct_ids_with_crisp_edges(instrument_dataset):
    """Every pixel's id is the tissue's or one instrument part's, and its depth is the ray cast depth of
    exactly that part's mesh at its pose: no pixel blends two surfaces."""
    scene, desc, out = instrument_dataset
    ids = {p.name: p.id for o, p in desc.parts() if o.kind == "instrument"}
    assert sorted(ids.values()) == [2, 3, 4, 5]
    classes = {p.id: p.cls for _, p in desc.parts()}
    assert classes[ids["jaw_upper"]] == classes[ids["jaw_lower"]] == "instrument_jaw"
    seen = set()
    rig = desc.rig
    for f in range(FRAMES):
        casters = _posed_raycasters(scene, desc, f)
        for eye in ds.EYES:
            _, gt = ds.read_frame(out, eye, f)
            seg, depth = gt["segmentation"], gt["depth"].astype(np.float64)
            assert set(np.unique(seg)) <= {1, *ids.values()}
            T = desc.camera_pose(f, eye)
            hits = {i: rc.cast(rig.left, T, normals="face") for i, rc in casters.items()}
            per_part = {i: hit["depth"].astype(np.float64) for i, hit in hits.items()}
            rays = cv.pixel_rays(32, 64, rig.intrinsics.K)
            for i in np.unique(seg):
                mask = seg == i
                ref = per_part[int(i)][mask]
                assert np.isfinite(ref).all()  # the ray does meet that part
                # float32 on both sides (Cycles, Open3D): depths agree to 1.4e-6 relative (measured) at rays
                # as grazing as cos 0.1 on the shaft's silhouette; the distance of the rendered point from the
                # part's surface (depth error x |cos(incidence)|) to 4e-7
                cos = np.abs(np.sum(hits[int(i)]["normals_cam"][mask] * rays[mask], axis=-1)) / np.linalg.norm(
                    rays[mask], axis=-1)
                error = np.abs(depth[mask] - ref) / ref
                assert error.max() < 2e-6 and (error * cos).max() < 1e-6, (int(i), error.max())
            nearest = np.argmin(np.stack([np.nan_to_num(per_part[i], nan=np.inf) for i in sorted(per_part)]), axis=0)
            union_ids = np.asarray(sorted(per_part))[nearest]
            assert (union_ids == seg).mean() > 0.995  # at most a pixel or two exactly on an edge
            seen |= set(np.unique(seg).tolist())
    assert {ids["shaft"], ids["jaw_upper"], ids["jaw_lower"]} <= seen, seen


def test_instrument_poses_and_table_come_from_the_model(instrument_dataset):
    scene, desc, out = instrument_dataset
    info = json.loads((out / "dataset.json").read_text())
    assert info["classes"] == {"tissue": 1, "instrument_shaft": 2, "instrument_wrist": 3, "instrument_jaw": 4}
    assert info["tracked_frames"] == {"6": {"name": "tip", "attached_to": "instrument/wrist"}}
    assert info["objects"]["4"]["moving"] and info["objects"]["4"]["part"] == "jaw_upper"
    for f in range(FRAMES):
        ids, poses = desc.tracked_poses(f)
        _, gt = ds.read_frame(out, "left", f)
        np.testing.assert_array_equal(gt["object_ids"], [1, 2, 3, 4, 5, 6])
        np.testing.assert_array_equal(gt["object_poses"], poses)
        assert gt["object_poses"].dtype == np.float64


@pytest.fixture(scope="module")
def moving_box_dataset(tmp_path_factory):
    """A 6 mm box (STL, millimetres) moved 1 mm per frame along +x in front of the plane; the camera moves
    too (0.5 mm per frame along y), so the box's flow is neither zero nor the camera's alone."""
    import trimesh

    folder = tmp_path_factory.mktemp("box_scene")
    trimesh.creation.box((6.0, 6.0, 6.0)).export(folder / "box.stl")
    start = [-0.002, 0.0, 0.035]
    keys = [{"frame": f, "position": [start[0] + STEP * f, start[1], start[2]], "euler_deg": [20, 30, 0]}
            for f in (0, FRAMES - 1)]
    config = {"objects": [{"kind": "mesh", "file": "box.stl", "scale": 0.001, "class": "box", "color": [0.2, 0.4, 0.8],
                           "motion": {"keyframes": keys}}]}
    scene, desc = _build(folder, config, _camera_poses((0.0, 0.0005, 0.0)))
    out = tmp_path_factory.mktemp("box_data") / "ds"
    render_dataset(scene, out, samples=1, denoise="none", progress=False)
    return scene, desc, out


def test_moving_object_pose_and_flow(moving_box_dataset):
    """object_poses hold exactly the keyed 1 mm/frame translation; the forward flow on the box is what that
    motion implies: back-project with depth and K, move by T(f+1) T(f)^-1, project into the next camera."""
    _, desc, out = moving_box_dataset
    box = next(p for o, p in desc.parts() if o.kind == "mesh")
    assert box.id == 2 and box.cls == "box"
    T0 = desc.tracked_poses(0)[1][1]
    for f in range(FRAMES):
        for eye in ds.EYES:
            _, gt = ds.read_frame(out, eye, f)
            assert list(gt["object_ids"]) == [1, 2]
            expected = T0.copy()
            expected[0, 3] += STEP * f
            np.testing.assert_allclose(gt["object_poses"][1], expected, rtol=0, atol=1e-12)
            if f == FRAMES - 1:
                continue
            mask = gt["segmentation"] == box.id
            assert mask.sum() > 30
            K, T_cam, T_next = gt["K"], gt["T_world_cam"], desc.camera_pose(f + 1, eye)
            points = cv.transform_points(T_cam, cv.backproject(gt["depth"].astype(np.float64), K))
            motion = desc.tracked_poses(f + 1)[1][1] @ cv.invert_pose(desc.tracked_poses(f)[1][1])
            moved = cv.transform_points(cv.invert_pose(T_next), cv.transform_points(motion, points))
            u1, v1 = cv.project(moved, K)
            u0, v0 = cv.pixel_grid(32, 64)
            flow = np.stack([u1 - u0, v1 - v0], axis=-1)
            np.testing.assert_allclose(gt["flow_forward"][mask], flow[mask], atol=2e-3)
            # the box moves against the camera: its flow is not the static scene's
            static = cv.flow_between_cameras(gt["depth"], K, T_cam, T_next)
            assert np.linalg.norm(gt["flow_forward"][mask] - static[mask], axis=-1).min() > 0.5
