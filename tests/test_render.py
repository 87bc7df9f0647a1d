"""Rendering a stereo dataset: analytic scenes with known answers, resume, errors.

Scenes are scene models (tiny: a few quads, 64x32, 1-2 samples) built and rendered through the one
Blender entry point (``rgbd2scene.stages.blender.run_task`` and ``rgbd2scene.stages.render.render_dataset``),
so the worker subprocess path is what is tested.
The ground-truth maps are compared with closed-form ray/plane intersections at pixel centres.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

from rgbd2scene import conventions as cv
from rgbd2scene.dataset import layout as ds
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.groundtruth.passes import MAPS, gt_from_passes, parse_maps
from rgbd2scene.scene.model import Light, Material, Part, SceneDescription, SceneObject, tissue_object
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig
from rgbd2scene.sensor import SensorOptions

BASELINE = 0.005
GT_KEYS = {"depth": ("float32", 2), "disparity": ("float32", 2), "normals": ("float32", 3),
           "flow_forward": ("float32", 3), "flow_backward": ("float32", 3), "segmentation": ("uint16", 2),
           "K": ("float64", 2), "T_world_cam": ("float64", 2), "object_ids": ("uint16", 1),
           "object_poses": ("float64", 3)}


# ================================================================ pure functions (no Blender)

def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _pose(R=None, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.eye(3) if R is None else R, t
    return T


def test_parse_maps():
    assert parse_maps("all") == MAPS
    assert parse_maps("none") == () and parse_maps("") == () and parse_maps(None) == ()
    assert parse_maps("normals,depth") == ("depth", "normals")
    assert parse_maps("flow") == ("flow_forward", "flow_backward")
    with pytest.raises(ValueError, match="bogus"):
        parse_maps("depth,bogus")


def test_gt_from_passes_arrays():
    h, w = 4, 6
    K = np.array([[50.0, 0, 2.5], [0, 40.0, 1.5], [0, 0, 1]])
    R = _rot("y", 30) @ _rot("x", -10)
    T = _pose(R, (0.1, 0.2, 0.3))
    depth = np.full((h, w), 0.05, np.float32)
    depth[0, 0] = 1e10  # Blender's background
    n_cam = np.array([0.2, -0.1, -1.0]) / np.linalg.norm([0.2, -0.1, -1.0])
    normal_world = np.tile(R @ n_cam, (h, w, 1)).astype(np.float32)
    normal_world[1, 1] *= -1  # a back-facing normal is turned to the camera
    vector = np.zeros((h, w, 4), np.float32)
    vector[..., 0], vector[..., 1], vector[..., 2], vector[..., 3] = 1.0, 2.0, 3.0, 4.0
    index = np.ones((h, w), np.float32)
    index[0, 0] = 0
    gt = gt_from_passes(depth, normal_world, vector, index, K, T, BASELINE,
                        object_ids=[1], object_poses=[np.eye(4)])
    for key, (dtype, ndim) in GT_KEYS.items():
        assert gt[key].dtype == dtype and gt[key].ndim == ndim, key
    assert np.isnan(gt["depth"][0, 0]) and np.isnan(gt["disparity"][0, 0])
    assert np.isnan(gt["normals"][0, 0]).all() and np.isnan(gt["flow_forward"][0, 0]).all()
    assert gt["segmentation"][0, 0] == 0 and gt["segmentation"][1, 1] == 1
    np.testing.assert_allclose(gt["disparity"][1:], 50.0 * BASELINE / 0.05, rtol=1e-6)
    np.testing.assert_allclose(gt["normals"][2, 3], n_cam, atol=1e-6)
    np.testing.assert_allclose(gt["normals"][1, 1], n_cam, atol=1e-6)  # flipped back to face the camera
    np.testing.assert_allclose(np.linalg.norm(gt["normals"][1:], axis=-1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(gt["flow_forward"][1, 1], [-3.0, 4.0])  # (-Z, +W)
    np.testing.assert_array_equal(gt["flow_backward"][1, 1], [1.0, -2.0])  # (+X, -Y)
    first = gt_from_passes(depth, None, vector, None, K, T, BASELINE, first=True, maps=("flow_backward",))
    last = gt_from_passes(depth, None, vector, None, K, T, BASELINE, last=True, maps=("flow_forward",))
    assert np.isnan(first["flow_backward"]).all() and np.isnan(last["flow_forward"]).all()
    assert set(first) == {"flow_backward", "K", "D", "T_world_cam", "object_ids", "object_poses"}
    with pytest.raises(ValueError, match="normals"):
        gt_from_passes(depth, None, None, None, K, T, BASELINE, maps=("normals",))


def test_dataset_layout(tmp_path):
    p = ds.frame_paths(tmp_path, "right", 7)
    assert p.rgb == tmp_path / "right" / "rgb" / "000007.png"
    assert p.gt == tmp_path / "right" / "gt" / "000007.npz"
    rgb = np.random.default_rng(0).integers(0, 255, (4, 6, 3), dtype=np.uint8)
    gt = {"depth": np.ones((4, 6), np.float32)}
    assert not ds.frame_done(tmp_path, 7)
    ds.write_frame(tmp_path, "left", 7, rgb, gt)
    assert not ds.frame_done(tmp_path, 7)
    ds.write_frame(tmp_path, "right", 7, rgb, gt)
    assert ds.frame_done(tmp_path, 7)
    image, back = ds.read_frame(tmp_path, "right", 7)
    np.testing.assert_array_equal(image, rgb)
    np.testing.assert_array_equal(back["depth"], gt["depth"])
    assert not [f for f in tmp_path.rglob(".*")]  # atomic writers leave nothing behind
    (tmp_path / "left" / "gt" / ".000008.x.npz").write_bytes(b"partial")
    assert ds.sweep_dead_runs(tmp_path) == 1
    # scratch folders: a live run's (its lock held) is kept whatever its age, a dead run's is swept
    dead = tmp_path / ds.WORK_DIR / "host-1-dead"
    dead.mkdir(parents=True)
    (dead / "lock").write_text("")
    (dead / "000003_data_L.exr").write_bytes(b"partial")
    with ds.scratch_dir(tmp_path) as live:
        (live / "000004_rgb_L.png").write_bytes(b"partial")
        assert ds.sweep_dead_runs(tmp_path) == 2  # the dead run's lock file and EXR
        assert not dead.exists() and (live / "000004_rgb_L.png").is_file()
    assert not live.exists() and ds.sweep_dead_runs(tmp_path) == 0
    assert not (tmp_path / ds.WORK_DIR).exists()
    with pytest.raises(ValueError, match="width"):
        ds.write_dataset_json(tmp_path, {"frames": 1})


# ================================================================ rendered scenes

pytest.importorskip("bpy")
pytest.importorskip("OpenEXR")

from rgbd2scene.files.meshio import write_ply  # noqa: E402
from rgbd2scene.geometry.mesh import Mesh  # noqa: E402
from rgbd2scene.stages.blender import BuildScene, Task, run_task  # noqa: E402
from rgbd2scene.stages.render import RenderError, render_dataset  # noqa: E402
from tests.conftest import write_scene_files  # noqa: E402

# non-centred principal point and fx != fy on purpose
INTR_A = Intrinsics(64, 32, 50.0, 44.0, 27.3, 18.6)
# scene B is built at 128x64 and rendered at 64x32 (K follows Intrinsics.resized)
INTR_B = Intrinsics(128, 64, 100.0, 90.0, 60.2, 33.1)
PLANE_Z = 0.05
EDGE_X = 0.005  # plane A ends here: the image right of it is background
DX = 0.001  # scene A: camera translation per frame along x
OCCLUDER = dict(x=(-0.010, -0.005), y=(-0.005, 0.004), z=0.04, id=2)
TILT_POINT = np.array([0.0, 0.0, 0.06])
TILT_NORMAL = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])


def _quad(corners, texture_value=128) -> SimpleNamespace:
    """Mesh of one quad (4 corners in order) for build_scene."""
    return SimpleNamespace(vertices=np.asarray(corners, float),
                           triangles=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                           uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
                           vertex_colors=np.full((4, 3), texture_value, np.uint8),
                           texture=np.full((4, 4, 3), texture_value, np.uint8))


def _write_scene(folder: Path, description: SceneDescription, mesh) -> Path:
    """Scene folder of ``description`` with ``mesh`` as the tissue, built by the Blender worker."""
    write_scene_files(folder, mesh, description)
    run_task(Task(BuildScene(str(folder), description.to_dict(), str(folder / "scene.blend"))))
    record = {"scene": description.to_dict(), "files": {"mesh": "mesh.ply"}, "test": True}
    (folder / "scene.json").write_text(json.dumps(record))
    return folder


def _occluder(folder: Path) -> SceneObject:
    """A small fronto-parallel quad (id 2) in front of the plane: local coordinates around its origin, which
    its (static) pose puts at (0, 0, z)."""
    x0, x1 = OCCLUDER["x"]
    y0, y1 = OCCLUDER["y"]
    quad = Mesh(vertices=np.array([(x0, y0, 0.0), (x1, y0, 0.0), (x1, y1, 0.0), (x0, y1, 0.0)]),
                triangles=np.array([[0, 1, 2], [0, 2, 3]], np.int32), vertex_colors=np.full((4, 3), 90, np.uint8))
    write_ply(folder / "objects" / "2.ply", quad)
    return SceneObject("instrument", "mesh", [Part(OCCLUDER["id"], "tip", "instrument", "objects/2.ply",
                                                   Material("as_captured"), _pose(t=(0.0, 0.0, OCCLUDER["z"])))])


@pytest.fixture(scope="module")
def scene_a(tmp_path_factory) -> Path:
    """Fronto-parallel plane at z=0.05 ending at x=0.005, an occluder with id 2; camera moves along +x."""
    poses = [_pose(t=(DX * f, 0.0, 0.0)) for f in range(3)]
    rig = StereoRig.parallel(INTR_A, BASELINE, clip_start=0.001, clip_end=2.0)
    folder = tmp_path_factory.mktemp("scene_a")
    desc = SceneDescription(rig, CameraPath(np.array(poses), fps=25.0, kind="test"), Light(),
                            [tissue_object("as_captured"), _occluder(folder)])
    z = PLANE_Z
    plane = _quad([(-0.5, -0.5, z), (-0.5, 0.5, z), (EDGE_X, 0.5, z), (EDGE_X, -0.5, z)])
    return _write_scene(folder, desc, plane)


def _poses_b() -> np.ndarray:
    return np.array([_pose(_rot("y", 2.0 * f) @ _rot("x", -1.0 * f), (0.001 * f, 0.0005 * f, 0.002 * f))
                     for f in range(3)])


@pytest.fixture(scope="module")
def scene_b(tmp_path_factory) -> Path:
    """A tilted plane filling the view; the camera rotates and translates."""
    n = TILT_NORMAL
    e1 = np.cross(n, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    corners = [TILT_POINT + 0.5 * (sx * e1 + sy * e2) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    rig = StereoRig.parallel(INTR_B, BASELINE, clip_start=0.001, clip_end=2.0)
    desc = SceneDescription(rig, CameraPath(_poses_b(), fps=25.0, kind="test"), Light(),
                            [tissue_object("wet_tissue")])
    return _write_scene(tmp_path_factory.mktemp("scene_b"), desc, _quad(corners))


@pytest.fixture(scope="module")
def dataset_a(scene_a, tmp_path_factory):
    out = tmp_path_factory.mktemp("data_a") / "ds"
    # exact colours: the ideal camera (fixed exposure at gain 1, no noise or vignetting: plain sRGB encoding)
    summary = render_dataset(scene_a, out, samples=2, denoise="none", progress=False, sensor=SensorOptions.ideal())
    return out, summary


@pytest.fixture(scope="module")
def dataset_b(scene_b, tmp_path_factory):
    out = tmp_path_factory.mktemp("data_b") / "ds"
    summary = render_dataset(scene_b, out, size=(64, 32), samples=1, progress=False, chunk=2)
    return out, summary


def _rays(K, h, w):
    return cv.pixel_rays(h, w, K)


def _analytic_a(K, T, h, w):
    """Depth, segmentation of scene A at pixel centres, and the distance (px) of each centre to an edge."""
    rays = _rays(K, h, w)
    o = T[:3, 3]
    depth = np.full((h, w), np.nan)
    seg = np.zeros((h, w), np.uint16)
    near_edge = np.zeros((h, w), bool)
    px = 1.0 / min(K[0, 0], K[1, 1])  # one pixel as a ray slope
    # plane (farther first, the occluder overwrites)
    for z, xr, yr, oid in ((PLANE_Z, (-0.5, EDGE_X), (-0.5, 0.5), 1),
                           (OCCLUDER["z"], OCCLUDER["x"], OCCLUDER["y"], OCCLUDER["id"])):
        lam = (z - o[2]) / rays[..., 2]
        x, y = o[0] + lam * rays[..., 0], o[1] + lam * rays[..., 1]
        inside = (x > xr[0]) & (x < xr[1]) & (y > yr[0]) & (y < yr[1])
        depth[inside], seg[inside] = lam[inside], oid
        margin = 0.05 * px * lam  # 0.05 px around each border
        for a, (lo, hi) in ((x, xr), (y, yr)):
            near_edge |= (np.abs(a - lo) < margin) | (np.abs(a - hi) < margin)
    return depth, seg, near_edge


def _analytic_plane(K, T, h, w, point, normal):
    rays = _rays(K, h, w)
    d_world = rays @ T[:3, :3].T
    lam = (normal @ (point - T[:3, 3])) / (d_world @ normal)
    n_cam = T[:3, :3].T @ normal
    n_cam = np.broadcast_to(n_cam, (h, w, 3))
    return lam, cv.orient_normals_to_camera(n_cam, rays)


def _angle_deg(a, b):
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(a * b, axis=-1)))


def _load(out, eye, f):
    return ds.read_frame(out, eye, f)


def test_default_denoiser_is_recorded(dataset_b):
    out, _ = dataset_b
    render = json.loads((out / "dataset.json").read_text())["render"]
    # the library's RGB defaults (rgbd2scene.rendering) are what the dataset records and resumes with
    assert (render["samples"], render["denoise"], render["prefilter"], render["denoise_quality"]) == (
        1, "oidn", "fast", "fast")


def test_denoiser_network_changes_only_the_images(dataset_b, scene_b, tmp_path):
    """``--denoise-quality`` reaches Cycles (the high network gives other pixels than the default fast one) and
    leaves the ground truth byte for byte as it was."""
    out, _ = dataset_b
    high = tmp_path / "high"
    render_dataset(scene_b, high, size=(64, 32), samples=1, progress=False, end=1, denoise_quality="high")
    paths = {name: ds.frame_paths(root, "left", 0) for name, root in (("fast", out), ("high", high))}
    assert paths["fast"].rgb.read_bytes() != paths["high"].rgb.read_bytes()
    assert paths["fast"].gt.read_bytes() == paths["high"].gt.read_bytes()


def test_dataset_files_and_json(dataset_a):
    out, summary = dataset_a
    assert summary["rendered"] == 3 and summary["skipped"] == 0
    info = json.loads((out / "dataset.json").read_text())
    for key in ("width", "height", "frames", "fps", "baseline", "K", "objects", "scene", "software", "seed",
                "conventions_version", "render"):
        assert key in info, key
    assert (info["width"], info["height"], info["frames"]) == (64, 32, 3)
    assert info["objects"]["2"] == {"name": "instrument", "part": "tip", "class": "instrument",
                                    "moving": False, "kind": "mesh"}
    assert info["classes"] == {"tissue": 1, "instrument": 2}
    assert info["conventions_version"] == cv.CONVENTIONS_VERSION
    assert info["render"]["gt"] == list(MAPS)
    assert len(info["scene"]["scene_json_sha1"]) == 40
    for f in range(3):
        for eye in ds.EYES:
            rgb, gt = _load(out, eye, f)
            assert rgb.shape == (32, 64, 3) and rgb.dtype == np.uint8
            for key, (dtype, ndim) in GT_KEYS.items():
                assert gt[key].dtype == dtype and gt[key].ndim == ndim, key
    assert not [p for p in out.rglob(".*")]  # no temporary files or scratch folder left


def test_poses_in_the_npz_are_the_scene_models(scene_a, dataset_a):
    """K, T_world_cam and object_poses are written from the scene model (float64), not read back from
    Blender: they equal the model's answers exactly, for every frame and eye."""
    out, _ = dataset_a
    model = SceneDescription.from_dict(json.loads((scene_a / "scene.json").read_text())["scene"])
    for f in range(3):
        ids, poses = model.tracked_poses(f)
        for eye in ds.EYES:
            _, gt = _load(out, eye, f)
            np.testing.assert_array_equal(gt["T_world_cam"], model.camera_pose(f, eye))
            np.testing.assert_array_equal(gt["K"], model.rig.intrinsics.K)
            np.testing.assert_array_equal(gt["object_ids"], ids)
            np.testing.assert_array_equal(gt["object_poses"], poses)
    assert list(ids) == [1, 2] and poses[1][2, 3] == OCCLUDER["z"]


def test_plane_depth_normals_disparity_segmentation(dataset_a):
    out, _ = dataset_a
    K = INTR_A.K
    for f in range(3):
        T_left = _pose(t=(DX * f, 0.0, 0.0))
        T_left_right = StereoRig.parallel(INTR_A, BASELINE).calibration.T_left_right
        for eye, T in (("left", T_left), ("right", T_left @ T_left_right)):
            rgb, gt = _load(out, eye, f)
            np.testing.assert_allclose(gt["T_world_cam"], T, atol=1e-6)
            np.testing.assert_array_equal(gt["K"], K)
            depth, seg, edge = _analytic_a(K, T, 32, 64)
            ok = ~edge
            surface = ok & np.isfinite(depth)
            background = ok & np.isnan(depth)
            assert surface.sum() > 500 and background.sum() > 100
            # depth: planar z at every pixel centre, to float32 precision
            np.testing.assert_allclose(gt["depth"][surface], depth[surface], rtol=1e-6)
            disparity = K[0, 0] * BASELINE / depth[surface]
            np.testing.assert_allclose(gt["disparity"][surface], disparity, rtol=1e-6)
            np.testing.assert_array_equal(gt["segmentation"][ok], seg[ok])
            # normals: (0, 0, -1) in the camera frame
            facing = np.broadcast_to([0, 0, -1.0], (surface.sum(), 3))
            np.testing.assert_allclose(gt["normals"][surface], facing, atol=1e-5)
            # background: NaN in every float map, 0 in the segmentation
            for key in ("depth", "disparity", "normals", "flow_forward", "flow_backward"):
                assert np.isnan(gt[key][background]).all(), key
            # ids and poses of the tracked objects
            np.testing.assert_array_equal(gt["object_ids"], [1, 2])
            np.testing.assert_allclose(gt["object_poses"][0], np.eye(4), atol=1e-7)
            np.testing.assert_allclose(gt["object_poses"][1], _pose(t=(0, 0, OCCLUDER["z"])), atol=1e-7)
            # as_captured texture 128: the PNG holds the texture bytes (Standard view, sRGB), as Blender saves
            inner = ndimage.binary_erosion(seg == 1, iterations=2)  # away from the filter's edge blend
            assert inner.sum() > 200
            assert np.abs(rgb[inner].astype(int) - 128).max() <= 1


def test_translation_flow_closed_form(dataset_a):
    """Camera moves +DX along x per frame over a static fronto-parallel plane: du = -fx*DX/z, dv = 0."""
    out, _ = dataset_a
    K = INTR_A.K
    for eye in ds.EYES:
        _, first = _load(out, eye, 0)
        _, middle = _load(out, eye, 1)
        _, last = _load(out, eye, 2)
        assert np.isnan(first["flow_backward"]).all() and np.isnan(last["flow_forward"]).all()
        for gt in (first, middle):
            T = gt["T_world_cam"]
            depth, _, edge = _analytic_a(K, T, 32, 64)
            ok = ~edge & np.isfinite(depth)
            du = -K[0, 0] * DX / depth[ok]
            np.testing.assert_allclose(gt["flow_forward"][ok][:, 0], du, atol=1e-3)
            np.testing.assert_allclose(gt["flow_forward"][ok][:, 1], 0.0, atol=1e-3)
        for gt in (middle, last):
            depth, _, edge = _analytic_a(K, gt["T_world_cam"], 32, 64)
            ok = ~edge & np.isfinite(depth)
            np.testing.assert_allclose(gt["flow_backward"][ok][:, 0], K[0, 0] * DX / depth[ok], atol=1e-3)
            np.testing.assert_allclose(gt["flow_backward"][ok][:, 1], 0.0, atol=1e-3)


def test_tilted_plane_resized_rotating_camera(dataset_b):
    out, summary = dataset_b
    assert summary["chunks"] == 2  # 3 frames in chunks of 2: two worker processes
    K = INTR_B.resized(64, 32).K
    info = json.loads((out / "dataset.json").read_text())
    np.testing.assert_allclose(info["K"], K)
    poses = _poses_b()
    rig = StereoRig.parallel(INTR_B.resized(64, 32), BASELINE)
    for f in range(3):
        for eye, T in (("left", poses[f]), ("right", rig.right_pose(poses[f]))):
            _, gt = _load(out, eye, f)
            np.testing.assert_allclose(gt["K"], K)
            np.testing.assert_allclose(gt["T_world_cam"], T, atol=2e-6)
            depth, normals = _analytic_plane(K, T, 32, 64, TILT_POINT, TILT_NORMAL)
            assert np.isfinite(gt["depth"]).all()
            np.testing.assert_allclose(gt["depth"], depth, rtol=4e-6)  # Cycles float32: measured 1.1e-6
            assert _angle_deg(gt["normals"].astype(float), normals).max() < 0.01  # contract: 0.1 deg
            # flow against reprojecting the analytic depth with the analytic poses (static scene)
            Tn = {"left": poses, "right": np.array([rig.right_pose(p) for p in poses])}[eye]
            if f < 2:
                ref = cv.flow_between_cameras(depth, K, T, Tn[f + 1])
                assert np.abs(gt["flow_forward"] - ref).max() < 2e-3
            if f > 0:
                ref = cv.flow_between_cameras(depth, K, T, Tn[f - 1])
                assert np.abs(gt["flow_backward"] - ref).max() < 2e-3


def test_left_right_consistency_through_disparity(dataset_b):
    """For a plane, disparity is affine in (u, v): the right eye at (u - d, v) sees the left pixel's point."""
    out, _ = dataset_b
    for f in range(3):
        _, left = _load(out, "left", f)
        _, right = _load(out, "right", f)
        d = left["disparity"].astype(float)
        u, v = cv.pixel_grid(32, 64)
        ur = u - d
        inside = (ur >= 0) & (ur <= 62)
        i0 = np.floor(ur[inside]).astype(int)
        a = ur[inside] - i0
        rows = v[inside].astype(int)
        dr = right["disparity"].astype(float)
        matched = (1 - a) * dr[rows, i0] + a * dr[rows, i0 + 1]
        assert inside.sum() > 1000
        np.testing.assert_allclose(matched, d[inside], rtol=1e-5)


def test_resume_skips_and_rerenders(scene_a, tmp_path):
    out = tmp_path / "ds"
    first = render_dataset(scene_a, out, frames=2, gt="depth,segmentation", samples=1, progress=False)
    assert first["rendered"] == 2
    files = sorted(p for p in out.rglob("*") if p.is_file())
    mtimes = {p: p.stat().st_mtime_ns for p in files}
    again = render_dataset(scene_a, out, frames=2, gt="depth,segmentation", samples=1, progress=False)
    assert again["rendered"] == 0 and again["skipped"] == 2
    assert {p: p.stat().st_mtime_ns for p in files} == mtimes
    # a deleted npz (and a killed run's leftover temp file) -> only that frame's ground truth again
    lost = ds.frame_paths(out, "left", 1).gt
    reference = dict(np.load(lost))
    lost.unlink()
    leftover = lost.parent / ".000001.abcd.npz"
    leftover.write_bytes(b"partial")
    os.utime(leftover, (1e9, 1e9))  # old: not a file of a run still going
    third = render_dataset(scene_a, out, frames=2, gt="depth,segmentation", samples=1, progress=False)
    assert third["rendered"] == 1 and third["skipped"] == 1
    assert lost.is_file()
    rgb1 = ds.frame_paths(out, "left", 1).rgb
    assert rgb1.stat().st_mtime_ns == mtimes[rgb1]  # the PNG was not rendered again
    again = dict(np.load(lost))
    assert set(again) == set(reference) and "normals" not in again
    np.testing.assert_array_equal(again["depth"], reference["depth"])
    assert not [p for p in out.rglob(".*")]
    # other settings into the same folder: refused
    with pytest.raises(UserError, match="other settings"):
        render_dataset(scene_a, out, frames=2, gt="all", samples=1, progress=False)
    with pytest.raises(UserError, match=r"other settings \(render\.engine\)"):  # GPU frames would not match
        render_dataset(scene_a, out, frames=2, gt="depth,segmentation", samples=1, engine="cycles-optix",
                       progress=False)
    record = json.loads((out / "dataset.json").read_text())["render"]
    assert record["engine"] == "cycles" and record["blender_engine"] == "CYCLES"
    info = json.loads((out / "dataset.json").read_text())  # an older dataset: Blender's engine name recorded
    info["render"]["engine"] = "CYCLES"
    (out / "dataset.json").write_text(json.dumps(info))
    assert render_dataset(scene_a, out, frames=2, gt="depth,segmentation", samples=1, progress=False)["skipped"] == 2


def test_gt_none_writes_only_images(scene_a, tmp_path):
    out = tmp_path / "ds"
    summary = render_dataset(scene_a, out, frames=1, gt="none", samples=1, progress=False)
    assert summary["rendered"] == 1
    assert ds.frame_paths(out, "left", 0).rgb.is_file() and ds.frame_paths(out, "right", 0).rgb.is_file()
    assert not (out / "left" / "gt").exists()
    again = render_dataset(scene_a, out, frames=1, gt="none", samples=1, progress=False)  # resumes: [] is "none"
    assert again["rendered"] == 0 and again["skipped"] == 1


def test_bad_inputs_are_user_errors(scene_a, tmp_path):
    with pytest.raises(UserError, match="not found"):
        render_dataset(tmp_path / "nope", tmp_path / "out", progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="scene.blend"):
        render_dataset(tmp_path / "empty", tmp_path / "out", progress=False)
    with pytest.raises(UserError, match="--frames"):
        render_dataset(scene_a, tmp_path / "out", frames=4, progress=False)
    with pytest.raises(UserError, match="--gt"):
        render_dataset(scene_a, tmp_path / "out", gt="depth,colour", progress=False)
    with pytest.raises(UserError, match="--size: 100000x100000 needs about .* GiB"):  # a memory estimate
        render_dataset(scene_a, tmp_path / "huge", size=(100000, 100000), progress=False)
    assert not (tmp_path / "huge").exists()
    (tmp_path / "afile").write_text("x")
    with pytest.raises(UserError, match="afile"):
        render_dataset(scene_a, tmp_path / "afile", progress=False)
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(UserError, match="not writable"):
            render_dataset(scene_a, locked / "out", progress=False)


def test_worker_failure_is_reported(scene_a, tmp_path):
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "scene.json").write_text((scene_a / "scene.json").read_text())
    (broken / "scene.blend").write_bytes(b"not a blend file")
    with pytest.raises(RenderError, match="worker failed"):
        render_dataset(broken, tmp_path / "out", frames=1, progress=False)


def test_description_from_blend_when_scene_json_lacks_it(scene_a, tmp_path):
    """scene.json without "scene": the description stored in the blend (scene["rgbd2scene"]) is used."""
    folder = tmp_path / "scene"
    folder.mkdir()
    (folder / "scene.blend").write_bytes((scene_a / "scene.blend").read_bytes())
    (folder / "scene.json").write_text(json.dumps({"mesh": {"file": "mesh.ply"}}))
    summary = render_dataset(folder, tmp_path / "ds", frames=1, gt="depth", samples=1, progress=False)
    assert summary["rendered"] == 1
    info = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert info["frames"] == 1 and info["objects"]["2"]["name"] == "instrument"
