"""Raw (distorted, unequal-eyed) stereo datasets: images and every map in the distorted pixel grid.

A textured plane seen by a scope whose two eyes have their own K and 5-coefficient distortion, a rotation and
a translation between them (X_right = R X_left + T), the camera moving: the ground truth is checked against an
outside computation (OpenCV's own undistortion and projection, the plane in closed form), ``verify`` passes,
``calibration.yaml`` reads back with ``cv2.FileStorage``, and ``render --rectify`` gives the rectified pair
of ``cv2.stereoRectify`` (alpha 0) with disparity.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from rgbd2scene.dataset import layout as ds
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.stereo import StereoCalibration
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig, read_scope_calibration
from rgbd2scene.sensor import SensorOptions

pytest.importorskip("bpy")

from rgbd2scene.stages.blender import BuildScene, Task, run_task  # noqa: E402
from rgbd2scene.stages.render import render_dataset  # noqa: E402
from rgbd2scene.verify import verify_dataset  # noqa: E402
from tests.conftest import write_scene_files  # noqa: E402

W, H, FRAMES = 64, 32, 3
K1 = np.array([[44.0, 0, 32.2], [0, 43.0, 15.6], [0, 0, 1]])
K2 = np.array([[45.0, 0, 30.9], [0, 44.5, 16.4], [0, 0, 1]])
D1 = np.array([-0.32, 0.11, 0.0012, -0.0008, -0.02])
D2 = np.array([-0.29, 0.08, -0.0006, 0.001, 0.01])
ANGLE = np.radians(1.2)
R = np.array([[np.cos(ANGLE), 0, np.sin(ANGLE)], [0, 1, 0], [-np.sin(ANGLE), 0, np.cos(ANGLE)]])
T = np.array([-0.0049, 0.00012, 0.0002])
POINT, NORMAL = np.array([0.0, 0.0, 0.05]), np.array([0.15, -0.1, -1.0]) / np.linalg.norm([0.15, -0.1, -1.0])


def _rig() -> StereoRig:
    return StereoRig(StereoCalibration(Camera(Intrinsics.from_K(K1, W, H), D1), Camera(Intrinsics.from_K(K2, W, H), D2),
                                       R, T), 0.001, 2.0)


def _poses() -> np.ndarray:
    poses = np.tile(np.eye(4), (FRAMES, 1, 1))
    poses[:, 0, 3] = 0.0007 * np.arange(FRAMES)
    poses[:, 1, 3] = -0.0003 * np.arange(FRAMES)
    return poses


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("raw_scene")
    e1 = np.cross(NORMAL, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(NORMAL, e1)
    corners = [POINT + 0.2 * (sx * e1 + sy * e2) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    rng = np.random.default_rng(0)
    plane = SimpleNamespace(vertices=np.asarray(corners), triangles=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                            uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
                            vertex_colors=np.full((4, 3), 128, np.uint8),
                            texture=rng.integers(0, 255, (64, 64, 3), dtype=np.uint8))
    desc = SceneDescription(_rig(), CameraPath(_poses(), fps=10.0, kind="test"), Light(),
                            [tissue_object("as_captured")])
    write_scene_files(folder, plane, desc)
    run_task(Task(BuildScene(str(folder), desc.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": desc.to_dict()}))
    return folder


@pytest.fixture(scope="module")
def raw(scene, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("raw_ds") / "ds"
    # the ideal sensor (fixed exposure, no noise, no vignetting): the images are compared with the texture
    render_dataset(scene, out, samples=1, denoise="none", sensor=SensorOptions.ideal(), progress=False)
    return out


def _plane_points(K, D, T_world_cam) -> np.ndarray:
    """World points of the plane under every pixel centre, along OpenCV's own (converged) undistortion."""
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.undistortPointsIter(np.stack([u, v], -1).reshape(-1, 1, 2), K, D, None, None, criteria).reshape(H, W, 2)
    rays = np.concatenate([xy, np.ones((H, W, 1))], -1) @ T_world_cam[:3, :3].T
    o = T_world_cam[:3, 3]
    lam = ((POINT - o) @ NORMAL) / (rays @ NORMAL)
    return o + lam[..., None] * rays, lam


def _project(K, D, T_world_cam, points) -> np.ndarray:
    T_cam_world = np.linalg.inv(T_world_cam)
    rvec = cv2.Rodrigues(T_cam_world[:3, :3])[0]
    uv, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, T_cam_world[:3, 3], K, D)
    return uv.reshape(points.shape[:-1] + (2,))


def test_raw_maps_match_opencv_and_the_plane(raw):
    meta = json.loads((raw / "dataset.json").read_text())
    assert meta["camera"]["rectified"] is False
    grid = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1)
    eyes = {"left": (K1, D1), "right": (K2, D2)}
    T_lr = np.eye(4)
    T_lr[:3, :3], T_lr[:3, 3] = R.T, -R.T @ T
    for f in range(FRAMES):
        gts = {eye: ds.read_frame(raw, eye, f)[1] for eye in eyes}
        for eye, (K, D) in eyes.items():
            gt = gts[eye]
            assert "disparity" not in gt and "correspondence" in gt
            np.testing.assert_array_equal(gt["K"], K)
            np.testing.assert_array_equal(gt["D"], D)
            T_left = _poses()[f]
            pose = T_left if eye == "left" else T_left @ T_lr
            np.testing.assert_allclose(gt["T_world_cam"], pose, atol=1e-12)
            points, lam = _plane_points(K, D, pose)
            assert np.isfinite(gt["depth"]).all()
            np.testing.assert_allclose(gt["depth"], lam, rtol=2e-6)  # planar z: the ray has unit z
            n = NORMAL @ pose[:3, :3]  # into the camera frame, facing it
            n = n if n[2] < 0 else -n
            assert np.abs(gt["normals"] - n).max() < 1e-5
            if f + 1 < FRAMES:
                nxt = _poses()[f + 1] if eye == "left" else _poses()[f + 1] @ T_lr
                flow = _project(K, D, nxt, points) - grid
                assert np.abs(gt["flow_forward"] - flow).max() < 1e-3
            other = "right" if eye == "left" else "left"
            K_o, D_o = eyes[other]
            T_other = T_left @ T_lr if other == "right" else T_left
            match = _project(K_o, D_o, T_other, points) - grid
            inside = ((match + grid >= -0.5) & (match + grid < (W - 0.5, H - 0.5))).all(-1)
            c = gt["correspondence"]
            assert np.array_equal(np.isfinite(c).all(-1), inside)  # a plane hides nothing: NaN = outside
            assert np.abs(c[inside] - match[inside]).max() < 1e-3
    report = verify_dataset(raw, progress=False)
    assert report.ok, [r for r in report.results if r.status == "fail"]
    checked = {r.check for r in report.results if r.status == "pass"}
    assert {"depth", "normals", "flow_fwd", "correspondence", "schema"} <= checked, checked


def test_raw_images_and_calibration_yaml(raw):
    """The raw images show the texture where the ground truth says each pixel's ray meets the plane."""
    texture = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8).astype(float).mean(-1)
    e1 = np.cross(NORMAL, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(NORMAL, e1)
    for eye, (K, D) in {"left": (K1, D1), "right": (K2, D2)}.items():
        rgb, gt = ds.read_frame(raw, eye, 1)
        assert rgb.shape == (H, W, 3)
        points, _ = _plane_points(K, D, gt["T_world_cam"])
        u = ((points - POINT) @ e1 / 0.2 + 1) / 2  # the quad's UVs; texture rows top first: v = 1 - row / 64
        v = ((points - POINT) @ e2 / 0.2 + 1) / 2
        expected = texture[np.clip(((1 - v) * 64).astype(int), 0, 63), np.clip((u * 64).astype(int), 0, 63)]
        grey = rgb.astype(float).mean(-1)
        aligned = np.corrcoef(expected.ravel(), grey.ravel())[0, 1]
        shifted = np.corrcoef(expected[:, 2:].ravel(), grey[:, :-2].ravel())[0, 1]
        assert aligned > 0.75 and aligned > shifted + 0.2, (eye, aligned, shifted)
    fs = cv2.FileStorage(str(raw / "calibration.yaml"), cv2.FILE_STORAGE_READ)
    try:
        for key, want in (("K1", K1), ("D1", D1), ("K2", K2), ("D2", D2), ("R", R), ("T", T)):
            np.testing.assert_allclose(fs.getNode(key).mat().ravel(), want.ravel(), err_msg=key)
        assert int(fs.getNode("image_width").real()) == W and int(fs.getNode("image_height").real()) == H
        assert fs.getNode("P1").empty()  # raw: no rectification in it
    finally:
        fs.release()
    rig = read_scope_calibration(raw / "calibration.yaml")  # --scope-calib reads what render writes
    np.testing.assert_allclose(rig.right.K, K2)
    np.testing.assert_allclose(rig.right.distortion, D2)
    np.testing.assert_allclose(rig.calibration.T, T)


def test_rectify_gives_the_rectified_pair_of_opencv(scene, tmp_path):
    out = tmp_path / "rect"
    render_dataset(scene, out, samples=1, denoise="none", progress=False, rectify=True)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(K1, D1, K2, D2, (W, H), R, T, flags=cv2.CALIB_ZERO_DISPARITY,
                                                alpha=0)
    _, gt = ds.read_frame(out, "left", 0)
    np.testing.assert_allclose(gt["K"], P1[:3, :3])
    assert not gt["D"].any() and "disparity" in gt
    turn = np.eye(4)
    turn[:3, :3] = R1.T
    np.testing.assert_allclose(gt["T_world_cam"], _poses()[0] @ turn, atol=1e-12)
    fs = cv2.FileStorage(str(out / "calibration.yaml"), cv2.FILE_STORAGE_READ)
    try:
        np.testing.assert_allclose(fs.getNode("P2").mat(), P2, atol=1e-9)
        np.testing.assert_allclose(fs.getNode("Q").mat(), Q, atol=1e-9)
    finally:
        fs.release()
    report = verify_dataset(out, progress=False)
    assert report.ok, [r for r in report.results if r.status == "fail"]


def test_bad_scope_calibrations_are_one_line_errors(tmp_path):
    def write(name, **arrays):
        path = tmp_path / name
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        for key, value in arrays.items():
            fs.write(key, value)
        fs.release()
        return path

    good = {"K1": K1, "D1": D1, "K2": K2, "D2": D2, "R": R, "T": T.reshape(3, 1), "image_width": W,
            "image_height": H}
    assert read_scope_calibration(write("good.yaml", **good)).baseline == pytest.approx(np.linalg.norm(T))
    with pytest.raises(UserError, match="missing key.*D2"):
        read_scope_calibration(write("missing.yaml", **{k: v for k, v in good.items() if k != "D2"}))
    with pytest.raises(UserError, match="rotation"):
        read_scope_calibration(write("shear.yaml", **{**good, "R": R + 0.05}))
    with pytest.raises(UserError, match="non-finite"):
        read_scope_calibration(write("nan.yaml", **{**good, "K1": K1 * np.nan}))
    with pytest.raises(UserError, match="folds"):
        read_scope_calibration(write("fold.yaml", **{**good, "D1": np.array([-3.0, 0, 0, 0, 0])}))
    # Files OpenCV itself rejects (its constructor raised a SystemError traceback before) and a matrix key
    # holding no matrix: one line naming the file, also for a dataset's calibration.yaml (realism).
    from rgbd2scene.capture.stereo import read_stereo_calibration

    (tmp_path / "empty.yaml").write_text("")
    (tmp_path / "broken.yaml").write_text("K1: [1, 2\n")
    (tmp_path / "list.yaml").write_text("%YAML:1.0\n---\n- 1\n- 2\n")
    scalar = write("scalar.yaml", **{**good, "K2": 3.0})
    for name, message in (("empty.yaml", "empty file"), ("broken.yaml", "not an OpenCV FileStorage file"),
                          ("list.yaml", "not an OpenCV FileStorage calibration"), ("scalar.yaml", "K2")):
        path = tmp_path / name
        with pytest.raises(UserError, match=message) as error:
            read_scope_calibration(path)
        assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)
        with pytest.raises(ValueError, match=message) as error:
            read_stereo_calibration(path)
        assert "\n" not in str(error.value)
    assert scalar.exists()


def test_a_lens_folding_inside_the_image_sees_nothing_beyond_the_fold(tmp_path):
    """An over-fitted lens folds before the image corners: those pixels have no ray (NaN maps, black pixels);
    the rest is exact, and verify passes."""
    folder = tmp_path / "scene"
    folder.mkdir()
    fold = Camera(Intrinsics(W, H, 40.0, 40.0, 31.5, 15.5), (-0.5, 0.0, 0.0, 0.0, 0.0))
    rig = StereoRig.parallel(fold, 0.004, 0.001, 2.0)
    assert 0.5 < fold.ray_share < 1.0
    corners = [(-0.2, -0.2, 0.05), (0.2, -0.2, 0.05), (0.2, 0.2, 0.05), (-0.2, 0.2, 0.05)]
    plane = SimpleNamespace(vertices=np.asarray(corners), triangles=np.array([[0, 2, 1], [0, 3, 2]], np.int32),
                            uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
                            vertex_colors=np.full((4, 3), 200, np.uint8), texture=np.full((4, 4, 3), 200, np.uint8))
    desc = SceneDescription(rig, CameraPath(np.tile(np.eye(4), (2, 1, 1)), fps=10.0, kind="test"), Light(),
                            [tissue_object("as_captured")])
    write_scene_files(folder, plane, desc)
    run_task(Task(BuildScene(str(folder), desc.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": desc.to_dict()}))
    out = tmp_path / "ds"
    render_dataset(folder, out, samples=1, denoise="none", progress=False)
    has_ray = np.isfinite(fold.rays()[..., 0])
    rgb, gt = ds.read_frame(out, "left", 0)
    assert np.array_equal(np.isfinite(gt["depth"]), has_ray)
    np.testing.assert_allclose(gt["depth"][has_ray], 0.05, rtol=2e-6)
    assert (rgb[~has_ray] == 0).all() and (rgb[has_ray].mean(-1) > 20).mean() > 0.95
    assert np.isnan(gt["normals"][~has_ray]).all() and (gt["segmentation"][~has_ray] == 0).all()
    report = verify_dataset(out, progress=False)
    assert report.ok, [r for r in report.results if r.status == "fail"]


def test_a_raw_bag_has_each_eyes_real_distortion(raw, tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from rgbd2scene.cli import main

    bag = tmp_path / "bag"
    assert main(["export-ros", str(raw), "-o", str(bag), "--ros", "2", "--quiet"]) == 0
    infos = {}
    with next(bag.glob("*.mcap")).open("rb") as f:
        for _, channel, _, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            assert not channel.topic.endswith("/disparity")  # a raw pair has none
            if channel.topic.endswith("camera_info"):
                infos.setdefault(channel.topic.split("/")[-2], decoded)
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(K1, D1, K2, D2, (W, H), R, T, flags=cv2.CALIB_ZERO_DISPARITY,
                                                alpha=0)
    for eye, K, D, Rr, P in (("left", K1, D1, R1, P1), ("right", K2, D2, R2, P2)):
        info = infos[eye]
        assert info.distortion_model == "plumb_bob"
        np.testing.assert_allclose(info.d, D)
        np.testing.assert_allclose(np.reshape(info.k, (3, 3)), K)
        np.testing.assert_allclose(np.reshape(info.r, (3, 3)), Rr, atol=1e-12)
        np.testing.assert_allclose(np.reshape(info.p, (3, 4)), P, atol=1e-9)


def test_the_contact_sheet_of_a_raw_pair_shows_its_correspondence(raw):
    """A raw dataset has no disparity: its contact sheet shows the correspondence to the right eye instead."""
    from rgbd2scene.pictures.contact_sheet import colorize_flow, frame_panels

    panels = {p.key: p for p in frame_panels(raw, 1)}
    assert "disparity" not in panels and "correspondence" in panels
    _, gt = ds.read_frame(raw, "left", 1, rgb=False)
    np.testing.assert_array_equal(panels["correspondence"].image, colorize_flow(gt["correspondence"]))
    finite = np.isfinite(gt["correspondence"]).all(axis=-1)
    assert finite.mean() > 0.5 and np.all(gt["correspondence"][finite][:, 0] < 0)  # the right eye sees it further left


def test_a_raw_scope_refuses_what_it_cannot_render_exactly(scene, tmp_path):
    """Motion blur needs the camera's motion within the shutter, which the worker's per-frame placement of a raw
    rig does not give; Blender's passes (the fallback of a scene folder without its geometry files) are a
    pinhole's. Both are one-line errors before anything is written."""
    import shutil

    with pytest.raises(UserError, match="^--motion-blur: not available for a raw scope"):
        render_dataset(scene, tmp_path / "blur", sensor=SensorOptions(motion_blur=0.5), progress=False)
    blend_only = tmp_path / "blend_only"
    blend_only.mkdir()
    for name in ("scene.blend", "scene.json"):
        shutil.copy(scene / name, blend_only / name)
    with pytest.raises(UserError, match="^--gt-source: Blender's passes are those of a pinhole"):
        render_dataset(blend_only, tmp_path / "passes", progress=False)
    assert not (tmp_path / "blur").exists() and not (tmp_path / "passes").exists()
