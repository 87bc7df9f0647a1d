"""verify_dataset on a tiny synthetic dataset ray cast from an analytic mesh, and on corrupted copies."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from rgbd2scene.conventions import backproject, disparity_from_depth, flow_between_cameras, transform_points
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.geometry.raycast import raycaster
from rgbd2scene.scene.paths import look_at
from rgbd2scene.scene.rig import StereoRig
from rgbd2scene.verify import Check, StaticMeshOracle, Tolerances, format_report, verify_dataset
from rgbd2scene.verify.checks import CHECKS

W, H, FRAMES = 64, 32, 3


def bumpy_grid(nx=121, ny=81):
    """Tilted bumpy height field z(x, y) about 3 cm ahead, triangles facing -z (the camera)."""
    x, y = np.meshgrid(np.linspace(-0.05, 0.012, nx), np.linspace(-0.035, 0.035, ny))
    z = 0.03 + 0.4 * x + 0.002 * np.sin(2 * np.pi * x / 0.03) * np.cos(2 * np.pi * y / 0.025)
    v = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    t = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return v, t.astype(np.int32)


def occluded_in(rc, depth, K, T, T_other):
    """Exact occlusion flags: the point leaves the other view, or a ray from the other eye hits earlier."""
    if T_other is None:
        return np.zeros(depth.shape, bool)
    pts = transform_points(T, backproject(depth, K))
    cam = np.linalg.inv(T_other)
    q = transform_points(cam, pts)
    u, v = K[0, 0] * q[..., 0] / q[..., 2] + K[0, 2], K[1, 1] * q[..., 1] / q[..., 2] + K[1, 2]
    outside = ~((u >= -0.5) & (u < W - 0.5) & (v >= -0.5) & (v < H - 0.5) & (q[..., 2] > 0))
    hit = rc.cast_rays(T_other[:3, 3], pts - T_other[:3, 3])["t"]
    return np.isfinite(depth) & (outside | (hit < 1 - 1e-4))


def write_dataset(root, vertices, triangles, rig, poses, mesh_file=None):
    """A dataset in the layout of CONVENTIONS section 4, ground truth by ray casting (smooth normals)."""
    rc = raycaster(vertices, triangles)
    K = rig.intrinsics.K
    eyes = {"left": list(poses), "right": [rig.right_pose(T) for T in poses]}
    for eye, eye_poses in eyes.items():
        for f, T in enumerate(eye_poses):
            cast = rc.cast(Camera.pinhole(K, W, H), T, normals="smooth")
            depth = cast["depth"]
            nan2 = np.full((H, W, 2), np.nan, np.float32)
            fwd = flow_between_cameras(depth, K, T, eye_poses[f + 1]) if f + 1 < len(eye_poses) else nan2
            bwd = flow_between_cameras(depth, K, T, eye_poses[f - 1]) if f > 0 else nan2
            gt = {
                "depth": depth,
                "disparity": disparity_from_depth(depth, K[0, 0], rig.baseline),
                "normals": cast["normals_cam"],
                "flow_forward": fwd.astype(np.float32),
                "flow_backward": bwd.astype(np.float32),
                "segmentation": np.isfinite(depth).astype(np.uint16),
                "K": K.astype(np.float64),
                "T_world_cam": np.asarray(T, np.float64),
                "object_ids": np.array([1], np.uint16),
                "object_poses": np.eye(4)[None],
                "occluded_forward": occluded_in(rc, depth, K, T, eye_poses[f + 1] if f + 1 < len(poses) else None),
                "occluded_backward": occluded_in(rc, depth, K, T, eye_poses[f - 1] if f > 0 else None),
            }
            (root / eye / "gt").mkdir(parents=True, exist_ok=True)
            (root / eye / "rgb").mkdir(parents=True, exist_ok=True)
            np.savez_compressed(root / eye / "gt" / f"{f:06d}.npz", **gt)
            shade = np.nan_to_num(-cast["normals_cam"][..., 2] * 255).astype(np.uint8)
            cv2.imwrite(str(root / eye / "rgb" / f"{f:06d}.png"), np.dstack([shade] * 3))
    meta = {"width": W, "height": H, "frames": len(poses), "fps": 30, "baseline": rig.baseline,
            "K": K.tolist(), "objects": [{"id": 1, "name": "tissue", "part": "surface", "class": "tissue"}],
            "scene": {"dir": str(root.parent), "mesh": str(mesh_file) if mesh_file else None}}
    (root / "dataset.json").write_text(json.dumps(meta))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    import open3d as o3d

    base = tmp_path_factory.mktemp("verify")
    v, t = bumpy_grid()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    mesh_file = base / "mesh.ply"
    o3d.io.write_triangle_mesh(str(mesh_file), mesh)
    rig = StereoRig.endoscope(W, H)
    # translation plus a turning view, so that camera and world frames differ
    poses = [look_at([-0.004 + 0.003 * f, 0.001 * f, 0.004], [0.002 * f - 0.003, 0.003, 0.033], [0.2, -1, 0])
             for f in range(FRAMES)]
    root = base / "dataset"
    write_dataset(root, v, t, rig, poses, mesh_file)
    return root


def corrupt(src, dst, eye, key, fn, frames=None):
    shutil.copytree(src, dst)
    for f in range(FRAMES) if frames is None else frames:
        p = dst / eye / "gt" / f"{f:06d}.npz"
        with np.load(p) as z:
            gt = {k: z[k] for k in z.files}
        gt[key] = fn(gt[key]).astype(gt[key].dtype)
        np.savez_compressed(p, **gt)
    return dst


def test_clean_dataset_passes(dataset):
    report = verify_dataset(dataset, progress=False)
    text = format_report(report)
    assert report.ok, text
    assert report.mesh is not None and report.mesh.endswith("mesh.ply")
    for check in ("schema", "depth", "normals", "disparity", "flow_fwd", "flow_bwd", "stereo", "coverage",
                  "occlusion"):
        assert report.status_of(check) in ("pass", "warn"), (check, text)
    assert "PASS" in text and "check" in text.splitlines()[1]
    depth_rows = [r for r in report.results if r.check == "depth" and r.metric.startswith("median")]
    assert depth_rows and all(r.value < 1e-4 for r in depth_rows)


def test_without_mesh_skips_mesh_checks(dataset, tmp_path):
    d = shutil.copytree(dataset, tmp_path / "d")
    meta = json.loads((d / "dataset.json").read_text())
    meta["scene"] = {"dir": str(tmp_path / "nowhere")}
    (d / "dataset.json").write_text(json.dumps(meta))
    report = verify_dataset(d, progress=False)
    assert report.ok, format_report(report)
    assert report.status_of("depth") == "skip" and report.status_of("normals") == "skip"
    assert report.status_of("flow_fwd") == "pass"


CORRUPTIONS = {
    "depth_scaled": ("left", "depth", lambda a: a * 1.01, "depth"),
    "flow_sign": ("left", "flow_forward", lambda a: -a, "flow_fwd"),
    "backward_flow_sign": ("right", "flow_backward", lambda a: -a, "flow_bwd"),
    "disparity_sign": ("left", "disparity", lambda a: -a, "disparity"),
    "right_depth_shift": ("right", "depth", lambda a: np.roll(a, 1, axis=1), "stereo"),
    "nan_to_zero": ("left", "depth", lambda a: np.nan_to_num(a, nan=0.0), "schema"),
    "flow_nan_to_zero": ("left", "flow_forward", lambda a: np.nan_to_num(a, nan=0.0), "schema"),
    "occlusion_inverted": ("left", "occluded_forward", lambda a: ~a, "occlusion"),
    "occlusion_one_px_off": ("left", "occluded_forward", lambda a: np.roll(a, 1, axis=1), "occlusion"),
}


@pytest.mark.parametrize("name", sorted(CORRUPTIONS))
def test_corruption_is_caught(dataset, tmp_path, name):
    eye, key, fn, check = CORRUPTIONS[name]
    d = corrupt(dataset, tmp_path / name, eye, key, fn)
    report = verify_dataset(d, progress=False)
    assert not report.ok
    assert report.status_of(check) == "fail", format_report(report)


def test_world_frame_normals_are_caught(dataset, tmp_path):
    d = shutil.copytree(dataset, tmp_path / "world_normals")
    for f in range(FRAMES):
        p = d / "left" / "gt" / f"{f:06d}.npz"
        with np.load(p) as z:
            gt = {k: z[k] for k in z.files}
        gt["normals"] = (gt["normals"].astype(np.float64) @ gt["T_world_cam"][:3, :3].T).astype(np.float32)
        np.savez_compressed(p, **gt)
    report = verify_dataset(d, progress=False)
    assert report.status_of("normals") == "fail", format_report(report)
    assert report.status_of("depth") == "pass"


def test_mask_holes_and_missing_files(dataset, tmp_path):
    # depth NaN where the mesh has surface (a hole the renderer should not have) -> depth mask check
    def hole(a):
        a = a.copy()
        a[10:20, 20:40] = np.nan
        return a

    d = corrupt(dataset, tmp_path / "hole", "left", "depth", hole, frames=[1])
    report = verify_dataset(d, progress=False)
    assert report.status_of("depth") == "fail"
    assert report.status_of("schema") == "fail"  # the other maps still have values there
    (d / "right" / "gt" / "000002.npz").unlink()
    report = verify_dataset(d, progress=False)
    assert any("missing" in p for p in report.problems)


def test_tolerances_and_errors(dataset, tmp_path):
    from rgbd2scene.errors import UserError

    report = verify_dataset(dataset, progress=False, tolerances=Tolerances(depth_median_mm=-1.0))
    assert report.status_of("depth") == "fail"
    with pytest.raises(UserError, match="dataset.json"):
        verify_dataset(tmp_path, progress=False)
    with pytest.raises(UserError, match="mesh"):
        verify_dataset(dataset, mesh_path=tmp_path / "absent.ply", progress=False)


def test_mesh_from_a_textured_obj(dataset, tmp_path):
    """An OBJ with one UV per vertex, as ``rgbd2scene mesh`` writes it: smooth normals need its shared vertices."""
    from rgbd2scene.files.meshio import write_textured_obj
    from rgbd2scene.geometry.mesh import Mesh

    v, t = bumpy_grid()
    uvs = (v[:, :2] - v[:, :2].min(axis=0)) / np.ptp(v[:, :2], axis=0)
    mesh = Mesh(vertices=v, triangles=t, vertex_colors=None, uvs=uvs.astype(np.float32), pixels=None,
                texture=np.full((4, 4, 3), 128, np.uint8))
    obj = write_textured_obj(tmp_path, mesh)["obj"]
    report = verify_dataset(dataset, mesh_path=obj, progress=False)
    assert report.status_of("normals") == "pass" and report.status_of("depth") == "pass", format_report(report)


def test_half_pixel_convention_slip_is_caught(dataset, tmp_path):
    """Depth rendered through (u + 0.5 - cx) / fx (Open3D's create_rays_pinhole) instead of pixel centres."""
    d = shutil.copytree(dataset, tmp_path / "half_pixel")
    rc = raycaster(*bumpy_grid())
    for f in range(FRAMES):
        p = d / "left" / "gt" / f"{f:06d}.npz"
        with np.load(p) as z:
            gt = {k: z[k] for k in z.files}
        K = gt["K"].copy()
        K[:2, 2] -= 0.5
        gt["depth"] = rc.cast(Camera.pinhole(K, W, H), gt["T_world_cam"], normals="none")["depth"]
        np.savez_compressed(p, **gt)
    report = verify_dataset(d, progress=False)
    shift = [r for r in report.results if r.check == "depth" and "shift" in r.metric and r.eye == "left"]
    assert shift and shift[0].status == "fail" and abs(shift[0].value - np.sqrt(0.5)) < 0.1


def _panel(path, key):
    """The image area of one panel of an error-map PNG (BGR)."""
    from rgbd2scene.verify import ERROR_PANELS, error_map_layout

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    x, y, w, h = error_map_layout(W, H)[2][ERROR_PANELS.index(key)]
    return img[y:y + h, x:x + w]


def test_error_maps(dataset, tmp_path):
    from rgbd2scene.verify import ERROR_PANELS, error_map_layout

    clean = verify_dataset(dataset, progress=False, error_maps=tmp_path / "clean")
    assert clean.ok
    names = [p.rsplit("/", 1)[-1] for p in clean.error_maps]
    for eye in ("left", "right"):
        assert sum(n.startswith(f"depth_{eye}_frame") for n in names) == 1, names
    assert all(n.endswith(".png") and len(n.split("frame")[1]) == len("000000.png") for n in names)
    assert sorted(p.name for p in (tmp_path / "clean").iterdir()) == sorted(names)  # no temporary files left
    assert clean.to_dict()["error_maps"] == clean.error_maps and "error maps (" in format_report(clean)
    sheet_w, sheet_h, boxes = error_map_layout(W, H)
    assert len(boxes) == len(ERROR_PANELS) and all(x + w <= sheet_w and y + h <= sheet_h for x, y, w, h in boxes)
    for p in clean.error_maps:
        img = cv2.imread(p, cv2.IMREAD_COLOR)
        assert img is not None and img.shape == (sheet_h, sheet_w, 3), p
        for key in ERROR_PANELS:  # every panel is drawn, none is the flat "not available" grey
            assert np.all(_panel(p, key) == 45, axis=-1).mean() < 0.5, (p, key)

    # depth 1 % too far on frame 1 of the left eye only: that frame becomes the left eye's worst depth frame
    d = corrupt(dataset, tmp_path / "scaled", "left", "depth", lambda a: a * 1.01, frames=[1])
    bad = verify_dataset(d, progress=False, error_maps=tmp_path / "bad")
    assert not bad.ok
    bad_png = tmp_path / "bad" / "depth_left_frame000001.png"
    assert str(bad_png) in bad.error_maps
    clean_png = next(p for p in clean.error_maps if "depth_left_" in p)
    luma = {}
    for name, png in (("clean", clean_png), ("bad", bad_png)):
        panel = cv2.cvtColor(_panel(png, "depth"), cv2.COLOR_BGR2GRAY).astype(float)
        luma[name] = panel.mean()
        magenta = np.all(_panel(png, "depth") == (255, 0, 255), axis=-1).mean()
        assert magenta < 0.01, (name, magenta)  # the valid masks agree
    # viridis on 0.01 um - 1 mm: ~0 error is dark purple, 1 % of ~3 cm (~300 um) is yellow-green
    assert luma["clean"] < 60 and luma["bad"] > luma["clean"] + 80, luma
    # the left eye's stereo panel changes too: its surface now lies behind the right eye's (drawn occluded)
    stereo = {n: cv2.cvtColor(_panel(p, "stereo"), cv2.COLOR_BGR2GRAY).mean() for n, p in
              (("clean", clean_png), ("bad", bad_png))}
    assert stereo["bad"] > stereo["clean"] + 30, stereo


def test_error_maps_hole_is_magenta(dataset, tmp_path):
    def hole(a):
        a = a.copy()
        a[10:20, 20:40] = np.nan
        return a

    d = corrupt(dataset, tmp_path / "hole", "right", "depth", hole, frames=[2])
    report = verify_dataset(d, progress=False, error_maps=tmp_path / "maps")
    png = tmp_path / "maps" / "depth_right_frame000002.png"
    assert str(png) in report.error_maps, report.error_maps
    magenta = np.all(_panel(png, "depth") == (255, 0, 255), axis=-1)  # BGR and RGB magenta alike
    assert abs(magenta.mean() - 200 / (W * H)) < 0.02, magenta.mean()


def test_error_maps_without_mesh(dataset, tmp_path):
    d = shutil.copytree(dataset, tmp_path / "d")
    meta = json.loads((d / "dataset.json").read_text())
    meta["scene"] = {"dir": str(tmp_path / "nowhere")}
    (d / "dataset.json").write_text(json.dumps(meta))
    report = verify_dataset(d, progress=False, error_maps=tmp_path / "maps")
    names = sorted(p.rsplit("/", 1)[-1] for p in report.error_maps)
    assert [n.split("_frame")[0] for n in names] == ["flow_left", "flow_right"], names  # no depth check
    assert np.all(_panel(report.error_maps[0], "depth") == 45, axis=-1).mean() > 0.9  # "not available"


def test_relative_scene_folder_is_relative_to_the_dataset(dataset, tmp_path, monkeypatch):
    d = shutil.copytree(dataset, tmp_path / "data" / "dataset")
    scene = tmp_path / "data" / "scene"
    scene.mkdir()
    shutil.copy(dataset.parent / "mesh.ply", scene / "mesh.ply")
    meta = json.loads((d / "dataset.json").read_text())
    meta["scene"] = {"dir": "../scene"}
    (d / "dataset.json").write_text(json.dumps(meta))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")  # not the dataset's parent: relative to the dataset, not here
    report = verify_dataset(d, progress=False)
    assert report.mesh is not None and Path(report.mesh).resolve() == (scene / "mesh.ply").resolve()
    assert report.status_of("depth") == "pass", format_report(report)


def test_damaged_npz_is_a_problem_line(dataset, tmp_path):
    from rgbd2scene.dataset import Dataset
    from rgbd2scene.errors import UserError

    d = shutil.copytree(dataset, tmp_path / "damaged")
    npz = d / "left" / "gt" / "000001.npz"
    npz.write_bytes(npz.read_bytes()[:1000])  # a killed copy: the zip directory is gone
    with pytest.raises(UserError, match="unreadable ground truth"):
        Dataset(d).gt("left", 1)
    report = verify_dataset(d, progress=False)
    assert "frame 000001 left: unreadable left/gt/000001.npz" in report.problems
    assert report.status_of("schema") == "fail" and report.status_of("depth") == "pass"


class DepthRangeCheck(Check):
    """A check defined outside the package: the largest depth of each eye and frame."""

    names = ("depth_range",)
    maps = ("depth",)

    def __init__(self, max_m: float):
        self.max_m = max_m

    def check_eye(self, frame):
        frame.add("depth_range", "max depth", float(np.nanmax(frame.depth)) * 1000.0, self.max_m * 1000.0, unit="mm")


def test_a_check_is_one_class_in_the_registry(dataset):
    report = verify_dataset(dataset, progress=False, checks=(*CHECKS, DepthRangeCheck(max_m=0.1)))
    rows = [r for r in report.results if r.check == "depth_range"]
    assert [r.eye for r in rows] == ["left", "right"] and all(r.status == "pass" for r in rows)
    assert all(20 < r.value < 60 for r in rows)  # the bumpy surface lies about 3 cm ahead
    assert report.results[-1].check == "depth_range" and report.ok  # reported after the registered checks
    tight = verify_dataset(dataset, progress=False, checks=(DepthRangeCheck(max_m=0.01),))
    assert not tight.ok and {r.check for r in tight.results} == {"depth_range"}


def test_static_mesh_oracle_ids_and_covered_pixels():
    v, t = bumpy_grid()
    first_half = np.arange(len(t)) < len(t) // 2
    oracle = StaticMeshOracle(raycaster(v, t), "bumpy", ids=[1], moving={2}, triangle_ids=np.where(first_half, 3, 4))
    rig = StereoRig.endoscope(W, H)
    T = look_at([-0.004, 0.0, 0.004], [-0.003, 0.003, 0.033], [0.2, -1, 0])
    cast = oracle.cast(0, rig.left, T)
    assert cast.depth.shape == (H, W) and cast.normals.shape == (H, W, 3) and cast.face_normals is not None
    assert np.array_equal(cast.instance_ids == 0, ~cast.hit) and set(np.unique(cast.instance_ids)) == {0, 3, 4}
    seg = np.array([[0, 1, 2, 5]], np.uint16)
    assert oracle.covers(0, seg).tolist() == [[True, True, False, False]]
    with pytest.raises(ValueError, match="one id per triangle"):
        StaticMeshOracle(raycaster(v, t), "bumpy", triangle_ids=[1, 2])


def test_a_per_frame_oracle_replaces_the_static_mesh(dataset, tmp_path):
    """Tissue that slides 1 mm per frame along x: the static mesh no longer explains the depth, a scene
    oracle that poses the mesh per frame does."""
    v, t = bumpy_grid()
    rc = raycaster(v, t)
    slide = np.array([0.001, 0.0, 0.0])

    def camera_in_mesh_frame(T, frame):  # moving the mesh by +s is moving the camera by -s
        T = np.array(T, np.float64)
        T[:3, 3] -= frame * slide
        return T

    d = shutil.copytree(dataset, tmp_path / "sliding")
    for eye in ("left", "right"):
        for f in range(FRAMES):
            p = d / eye / "gt" / f"{f:06d}.npz"
            with np.load(p) as z:
                gt = {k: z[k] for k in z.files}
            gt["depth"] = rc.cast(Camera.pinhole(gt["K"], W, H), camera_in_mesh_frame(gt["T_world_cam"], f),
                                  normals="none")["depth"]
            np.savez_compressed(p, **gt)

    class SlidingTissue:
        source, shading = "bumpy grid sliding 1 mm per frame", "smooth"

        def __init__(self):
            self.mesh = StaticMeshOracle(rc, self.source)

        def cast(self, frame, camera, T_world_cam):
            return self.mesh.cast(frame, camera, camera_in_mesh_frame(T_world_cam, frame))

        def covers(self, frame, segmentation):
            return np.ones(segmentation.shape, bool)

    assert verify_dataset(d, progress=False).status_of("depth") == "fail"
    report = verify_dataset(d, progress=False, oracle=SlidingTissue())
    assert report.status_of("depth") == "pass", format_report(report)
    assert report.mesh == SlidingTissue.source
    with pytest.raises(ValueError, match="not both"):
        verify_dataset(d, progress=False, oracle=SlidingTissue(), mesh_path=dataset.parent / "mesh.ply")


def test_occlusion_reference_leaves_points_between_samples_across_an_edge_unjudged():
    """A far wall, its left half behind a near wall (depth step between columns 3 and 4 of camera b): a far
    point projecting between the two columns has a matching sample and a nearer one, and which side of the
    edge it falls on is not in the samples: neither clearly visible nor clearly hidden. Off the edge, far
    points are clearly visible (right) or hidden (left); a point projecting outside is hidden."""
    from rgbd2scene.verify.checks.occlusion import occlusion_reference

    camera = Camera.pinhole(np.array([[10.0, 0, 3.5], [0, 10.0, 3.5], [0, 0, 1]]), 8, 8)
    depth_b = np.where(np.arange(8) < 4, 0.5, 1.0)[None, :].repeat(8, axis=0)
    u = np.array([1.0, 3.5, 6.0, 20.0])  # behind the near wall, between the columns, in the open, outside
    points = np.full((8, 8, 3), np.nan)  # (H, W, 3) of camera b's size, as a frame's surface points are
    points[0, :4] = np.stack([(u - 3.5) / 10.0, np.zeros(4), np.ones(4)], axis=-1)
    visible, hidden = occlusion_reference(points, camera, np.eye(4), depth_b, 0.01)
    assert visible[0, :4].tolist() == [False, False, True, False] and not visible[1:].any()
    assert hidden[0, :4].tolist() == [True, False, False, True] and not hidden[1:].any()
