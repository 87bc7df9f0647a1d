"""Moving and deforming surfaces: ground truth of breathing tissue and of an object sliding over it.

Scenes are scene models built and rendered through the one Blender entry point (64x32, a few frames), with
the ground truth from Blender's passes (``gt_source="blender"``, the cross-check of the scene model's maps,
which ``tests/test_model_gt.py`` compares). The references are independent of Blender: the deformation
formula and the model's poses in numpy, ray casting the model (``SceneGeometry``), and the other maps of the
same dataset.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rgbd2scene import conventions as cv
from rgbd2scene.dataset import layout as ds
from rgbd2scene.files.meshio import write_ply
from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.groundtruth.scene_geometry import SceneGeometry
from rgbd2scene.scene.deformation import Deformation, SurfaceAnchor, rest_normals
from rgbd2scene.scene.model import (
    Light,
    Material,
    Part,
    SceneDescription,
    SceneObject,
    TrackedFrame,
    tissue_object,
)
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig
from tests.conftest import flat_grid

pytest.importorskip("bpy")

from rgbd2scene.stages.blender import BuildScene, Task, run_task  # noqa: E402
from rgbd2scene.stages.render import render_dataset  # noqa: E402
from rgbd2scene.verify import verify_dataset  # noqa: E402

INTR = Intrinsics(64, 32, 50.0, 48.0, 31.7, 15.2)
BASELINE = 0.005
FRAMES = 4
PLANE_Z = 0.05


def _grid(z: float, half: float = 0.05, n: int = 41) -> Mesh:
    return flat_grid(z, half, n)


def _build(folder: Path, description: SceneDescription) -> Path:
    run_task(Task(BuildScene(str(folder), description.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": description.to_dict()}))
    return folder


def _camera(poses) -> tuple[StereoRig, CameraPath]:
    return (StereoRig.parallel(INTR, BASELINE, clip_start=0.001, clip_end=2.0),
            CameraPath(np.asarray(poses, float), fps=10.0, kind="test"))


@pytest.fixture(scope="module")
def breathing(tmp_path_factory):
    """Tissue (a plane grid) breathing with a large, travelling displacement; a still camera; a tracked frame
    anchored to the surface."""
    folder = tmp_path_factory.mktemp("breathing")
    mesh = _grid(PLANE_Z)
    write_ply(folder / "mesh.ply", mesh)
    rest = mesh.vertices.astype(np.float32).astype(np.float64)
    normals = rest_normals(rest, mesh.triangles)
    deformation = Deformation.preset("breathing", amplitude_m=0.003, frequency_hz=1.0, extent_m=0.02,
                                     wavelength_m=0.04, centre=(0.002, -0.001, PLANE_Z))
    tissue = tissue_object("as_captured", texture=None)
    tissue.parts[0].deformation = deformation
    tri = 1234
    corners = mesh.triangles[tri]
    anchor = SurfaceAnchor(tuple(corners), (0.2, 0.3, 0.5), rest[corners], normals[corners])
    offset = np.eye(4)
    offset[:3, 3] = anchor.point()
    tissue.tracked_frames.append(TrackedFrame(500, "lesion", "surface", offset, anchor))
    rig, path = _camera([np.eye(4)] * FRAMES)
    description = SceneDescription(rig, path, Light(), [tissue])
    scene = _build(folder, description)
    out = tmp_path_factory.mktemp("breathing_ds") / "ds"
    render_dataset(scene, out, samples=1, denoise="none", progress=False, gt_source="blender")
    return scene, out, description


def test_breathing_ground_truth_follows_the_deformation(breathing):
    scene, out, description = breathing
    tissue = description.objects[0].parts[0]
    geometry = SceneGeometry(description, scene)
    rest = geometry.meshes[0].vertices
    moved = False
    for f in range(FRAMES):
        # DATASET/geometry holds the deformed vertices of the formula, in the rest mesh's vertex order
        with np.load(ds.geometry_path(out, f)) as z:
            vertices = z["vertices_1"]
        expected = tissue.deformation.displace(rest, geometry.meshes[0].normals, description.time(f))
        np.testing.assert_allclose(vertices, expected, atol=1e-7)
        moved |= np.abs(expected - rest).max() > 1e-3
        for eye in ds.EYES:
            _, gt = ds.read_frame(out, eye, f)
            T = description.camera_pose(f, eye)
            ref = geometry.cast(f, Camera(INTR), T)
            both = np.isfinite(gt["depth"]) & np.isfinite(ref["depth"])
            assert both.mean() > 0.9
            # depth and normals of the deformed surface
            np.testing.assert_allclose(gt["depth"][both], ref["depth"][both], rtol=2e-6)
            cos = np.sum(gt["normals"][both] * ref["normals_cam"][both], axis=-1)
            assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.05
            # the tissue's own motion is in the flow: a still camera, yet the surface points move
            if f < FRAMES - 1:
                points = geometry.moved_points(ref["triangle_ids"], ref["uvs"], f + 1)
                u, v = cv.project(cv.transform_points(cv.invert_pose(description.camera_pose(f + 1, eye)), points),
                                  INTR.K)
                gu, gv = cv.pixel_grid(INTR.height, INTR.width)
                expected_flow = np.stack([u - gu, v - gv], -1)
                ok = both & np.all(np.isfinite(expected_flow), -1)
                err = np.linalg.norm(gt["flow_forward"][ok] - expected_flow[ok], axis=-1)
                assert np.median(err) < 2e-3 and np.percentile(err, 99) < 2e-2
                assert np.abs(expected_flow[ok]).max() > 0.2  # a motion the check can see
    assert moved


def test_tracked_frame_on_the_tissue_moves_with_the_surface(breathing):
    scene, out, description = breathing
    anchor = description.objects[0].tracked_frames[0].anchor
    origins = []
    for f in range(FRAMES):
        _, gt = ds.read_frame(out, "left", f, rgb=False)
        i = list(gt["object_ids"]).index(500)
        with np.load(ds.geometry_path(out, f)) as z:
            corners = z["vertices_1"][list(anchor.vertices)].astype(np.float64)
        surface_point = np.asarray(anchor.weights) @ corners
        np.testing.assert_allclose(gt["object_poses"][i][:3, 3], surface_point, atol=1e-7)
        R = gt["object_poses"][i][:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        origins.append(surface_point)
    assert np.ptp(np.array(origins)[:, 2]) > 1e-4  # it rides the breathing surface
    assert 500 not in np.unique(gt["segmentation"])  # tracked frames never appear in the segmentation


def test_verify_checks_deforming_ground_truth(breathing, tmp_path):
    scene, out, _ = breathing
    report = verify_dataset(out, progress=False)
    assert report.ok, [r for r in report.results if r.status == "fail"]
    rows = {(r.check, r.eye, r.metric): r for r in report.results}
    assert rows[("flow_fwd", "left", "median endpoint error")].status == "pass"
    assert rows[("segmentation", "left", "ids differing from the scene off edges (frac)")].status == "pass"
    assert rows[("occlusion", "left", "occluded_forward contradicting geometry (frac)")].status == "pass"
    # flow that ignores the tissue's own motion (a static scene under a still camera: zero) is caught
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    (broken / "dataset.json").write_text((out / "dataset.json").read_text().replace(
        json.loads((out / "dataset.json").read_text())["scene"]["dir"], str(scene)))
    for f in range(FRAMES):
        for eye in ds.EYES:
            path = ds.frame_paths(broken, eye, f).gt
            with np.load(path) as z:
                gt = {k: z[k] for k in z.files}
            gt["flow_forward"] = np.where(np.isfinite(gt["flow_forward"]), 0.0, np.nan).astype(np.float32)
            ds.write_gt(path, gt)
    bad = verify_dataset(broken, progress=False)
    assert not bad.ok
    assert {r.check for r in bad.results if r.status == "fail"} == {"flow_fwd"}


@pytest.fixture(scope="module")
def sliding(tmp_path_factory):
    """A still camera over a plane; a small square slides +x by 1 mm per frame in front of it."""
    folder = tmp_path_factory.mktemp("sliding")
    write_ply(folder / "mesh.ply", _grid(PLANE_Z, n=3))
    square = Mesh(vertices=np.array([(-0.004, -0.004, 0.0), (0.004, -0.004, 0.0), (0.004, 0.004, 0.0),
                                     (-0.004, 0.004, 0.0)]),
                  triangles=np.array([[0, 2, 1], [0, 3, 2]], np.int32), vertex_colors=np.full((4, 3), 60, np.uint8))
    write_ply(folder / "objects" / "2.ply", square)
    poses = np.stack([np.eye(4)] * FRAMES)
    poses[:, 0, 3] = -0.003 + 0.001 * np.arange(FRAMES)
    poses[:, 2, 3] = 0.04
    slider = SceneObject("slider", "mesh", [Part(2, "body", "instrument", "objects/2.ply", Material("as_captured"),
                                                 poses)])
    rig, path = _camera([np.eye(4)] * FRAMES)
    description = SceneDescription(rig, path, Light(), [tissue_object("as_captured", texture=None), slider])
    scene = _build(folder, description)
    out = tmp_path_factory.mktemp("sliding_ds") / "ds"
    render_dataset(scene, out, samples=1, denoise="none", progress=False, gt_source="blender")
    return scene, out, description


def test_moving_object_pose_flow_and_occlusion(sliding):
    scene, out, description = sliding
    K = INTR.K
    for f in range(FRAMES):
        _, gt = ds.read_frame(out, "left", f, rgb=False)
        ids, poses = description.tracked_poses(f)
        np.testing.assert_array_equal(gt["object_ids"], ids)
        np.testing.assert_array_equal(gt["object_poses"], poses)  # exactly the model's, float64
        seg = gt["segmentation"]
        assert set(np.unique(seg)) == {1, 2}
        if f == FRAMES - 1:
            continue
        # the square moves 1 mm in x at z = 4 cm: fx * 0.001 / 0.04 px, no vertical motion
        on_square = seg == 2
        expected = np.broadcast_to([K[0, 0] * 0.001 / 0.04, 0.0], (on_square.sum(), 2))
        np.testing.assert_allclose(gt["flow_forward"][on_square], expected, atol=1e-3)
        # the plane is still: zero flow, also where the square covers it next frame (occluded, flow kept)
        on_plane = seg == 1
        np.testing.assert_allclose(gt["flow_forward"][on_plane], 0.0, atol=1e-3)
        _, nxt = ds.read_frame(out, "left", f + 1, rgb=False)
        covered_next = on_plane & (nxt["segmentation"] == 2)
        assert covered_next.sum() >= 5  # about a column of the square's height
        assert gt["occluded_forward"][covered_next].all()
        visible_next = on_plane & (nxt["segmentation"] == 1)
        assert not gt["occluded_forward"][visible_next].any()
        assert not gt["occluded_forward"][on_square].any()  # the square itself stays in view
    report = verify_dataset(out, progress=False)
    assert report.ok, [r for r in report.results if r.status == "fail"]


@pytest.mark.parametrize("fixture, beyond_view", [("breathing", True), ("sliding", False)])
def test_data_renders_of_what_is_in_view_equal_those_of_the_whole_scene(fixture, beyond_view, request, tmp_path):
    """The data render syncs only the triangles the eyes see and their neighbours (view culling): every
    ground-truth array is the same, bit for bit, as with the whole scene synced."""
    scene, out, description = request.getfixturevalue(fixture)
    geometry = SceneGeometry(description, scene)
    support = geometry.view_support(0, 1, Camera(INTR))
    assert (len(support) < len(geometry.meshes[0].vertices)) == beyond_view  # breathing: a grid wider than the view
    whole = tmp_path / "whole"
    render_dataset(scene, whole, samples=1, denoise="none", progress=False, view_culling=False,
                   gt_source="blender")
    for eye in ("left", "right"):
        for f in range(FRAMES):
            _, culled = ds.read_frame(out, eye, f, rgb=False)
            _, reference = ds.read_frame(whole, eye, f, rgb=False)
            assert culled.keys() == reference.keys()
            for key in reference:
                np.testing.assert_array_equal(culled[key], reference[key], err_msg=f"{eye} {f} {key}")
