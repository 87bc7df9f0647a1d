"""Stereo endoscope frames: calibration files, rectification, confident stereo depth, the Hamlyn phantom scene.

Synthetic cases have exact answers (projected 3-D points, a textured slanted plane, a textured sphere); the real Hamlyn
phantom frame (no ground truth) is held to plausibility at the calibrated scale, to exact geometry of
the frames involved (the mesh in the unrectified left camera) and to a render through the capture camera.
"""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial.transform import Rotation

from rgbd2scene.capture.readers import read_rgb
from rgbd2scene.capture.stereo import (
    STEREO_SMOOTH_ITERATIONS,
    RectifiedPair,
    StereoOptions,
    elas_available,
    left_right_consistent,
    load_stereo_capture,
    read_stereo_calibration,
    rectify,
    stereo_depth,
)
from rgbd2scene.conventions import invert_pose, pixel_grid, transform_points
from rgbd2scene.geometry.stereo import DISTORTION_SIZES, StereoCalibration
from rgbd2scene.reconstruct.mesh import grid_mesh
from rgbd2scene.reconstruct.pipeline import reconstruct
from rgbd2scene.reconstruct.smooth import boundary_vertices, smooth_mesh

HAMLYN = "hamlyn_silicone_heart_phantom_stereo"
LEFT, RIGHT = "f7_dynamic_deint_L_0100.png", "f7_dynamic_deint_R_0100.png"


def synthetic_calibration(n_coeffs: int = 5) -> dict:
    """A 320x240 pair, 5 mm baseline, slightly rotated right camera, visible distortion of each model size."""
    coeffs = {4: [-0.25, 0.08, 0.001, -0.0005], 5: [-0.25, 0.08, 0.001, -0.0005, -0.01],
              8: [-0.25, 0.08, 0.001, -0.0005, -0.01, 0.02, 0.01, 0.0],
              12: [-0.25, 0.08, 0.001, -0.0005, -0.01, 0.02, 0.01, 0.0, 0.001, 0.0, -0.001, 0.0],
              14: [-0.25, 0.08, 0.001, -0.0005, -0.01, 0.02, 0.01, 0.0, 0.001, 0.0, -0.001, 0.0, 0.002, -0.001]}
    R = Rotation.from_rotvec([0.01, -0.02, 0.005]).as_matrix()
    return {"K_left": [[300.0, 0, 158.0], [0, 302.0, 121.0], [0, 0, 1]], "D_left": coeffs[n_coeffs],
            "K_right": [[298.0, 0, 163.0], [0, 301.0, 118.0], [0, 0, 1]], "D_right": coeffs[n_coeffs],
            "R": R.tolist(), "T": [-0.005, 0.0001, 0.0002], "image_size": [320, 240]}


# --------------------------------------------------------------------------------------------- calibration


def test_hamlyn_folder_and_json_give_the_same_calibration(shared_samples, tmp_path):
    folder = shared_samples / HAMLYN
    calib = read_stereo_calibration(folder, image_size=(360, 288))
    assert calib.size == (360, 288) and calib.D_left.size == 5
    assert np.isclose(calib.baseline, 0.005521, atol=1e-6)  # calib.l2r.4x4 is in millimetres
    assert np.allclose(calib.T, np.loadtxt(folder / "calib.l2r.4x4")[:3, 3] / 1000.0)
    data = {key: np.asarray(value).tolist() for key, value in calib.to_dict().items() if key != "baseline_m"}
    (tmp_path / "calib.json").write_text(json.dumps(data))
    again = read_stereo_calibration(tmp_path / "calib.json")
    for key in ("K_left", "D_left", "K_right", "D_right", "R", "T"):
        assert np.array_equal(getattr(again, key), getattr(calib, key)), key


@pytest.mark.parametrize("change, message", [
    (lambda d: d.pop("R"), "missing key"),
    (lambda d: d.pop("image_size"), "missing the image size"),
    (lambda d: d.update(D_left=[0.1] * 6), "D_left has 6 coefficients"),
    (lambda d: d.update(T=[-5.0, 0.0, 0.0]), "millimetres"),
    (lambda d: d.update(T=[0.005, 0.0, 0.0]), "left and right swapped"),
    (lambda d: d.update(T=[0.0, -0.005, 0.0]), "vertically"),
    (lambda d: d.update(R=[[1, 0, 0], [0, 2, 0], [0, 0, 1]]), "R is not a rotation"),
    (lambda d: d.update(K_left=[[300.0, 0, 900.0], [0, 300.0, 120.0], [0, 0, 1]]), "principal point"),
    (lambda d: d.update(K_right=[1, 2, 3]), "K_right must have 9 numbers"),
    (lambda d: d.update(K_left=[[300.0, 0, 158.0], [0, 302.0, 121.0], [0.1, 0, 1]]), "K_left is not a camera matrix"),
    (lambda d: d.update(R=[[1, 2e-3, 0], [0, 1, 0], [0, 0, 1]]), "R is not a rotation"),  # beyond ROTATION_SNAP
    (lambda d: d.update(D_right=[-3.0, 0, 0, 0, 0]), "D_right: the lens model folds"),
])
def test_bad_calibrations_name_the_problem(change, message):
    data = synthetic_calibration()
    change(data)
    with pytest.raises(ValueError, match=message):
        StereoCalibration.from_dict(data)


def test_a_rotation_written_with_few_decimals_is_replaced_by_the_nearest_rotation(capsys):
    """A calibration file whose R was rounded to 4 decimals (off a rotation by about 1e-4) is read, with the
    nearest rotation in its place (so the right eye's pose stays rigid) and one warning line; an exact R is
    kept bit for bit."""
    data = synthetic_calibration()
    exact = StereoCalibration.from_dict(data)
    angle = np.radians(2.0)
    rotated = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    rounded = np.round(rotated, 4)
    assert np.abs(rounded.T @ rounded - np.eye(3)).max() > 1e-6  # the case: off by more than the tolerance
    calib = StereoCalibration.from_dict({**data, "R": rounded.tolist()})
    R = np.asarray(calib.R)
    assert np.abs(R.T @ R - np.eye(3)).max() < 1e-12 and abs(np.linalg.det(R) - 1) < 1e-12
    assert np.abs(R - rounded).max() < 1e-4 and np.abs(R - rotated).max() < 1e-4
    assert "the nearest rotation is used" in capsys.readouterr().err
    assert np.array_equal(np.asarray(exact.R), np.asarray(data["R"], dtype=np.float64))


def test_a_slightly_scaled_rotation_is_replaced_and_the_eyes_must_share_one_size():
    """R = 1.0004 I (orthogonality off by 8e-4; det off by 1.2e-3) loaded before the one calibration type and
    still does, as the nearest rotation; a pair whose eyes differ in image size is refused (resized() keeps
    one size for both)."""
    data = synthetic_calibration()
    calib = StereoCalibration.from_dict({**data, "R": (1.0004 * np.asarray(data["R"])).tolist()})
    assert np.allclose(np.asarray(calib.R), np.asarray(data["R"]), atol=1e-12)
    exact = StereoCalibration.from_dict(data)
    with pytest.raises(ValueError, match="differ in size"):
        StereoCalibration(exact.left, exact.right.resized(160, 120), exact.R, exact.T)


def test_path_capture_names_a_bad_stereo_calibration_in_the_capture_record():
    from rgbd2scene.errors import UserError
    from rgbd2scene.stages.scene import SceneOptions, capture_camera

    data = synthetic_calibration()
    data["R"] = [[1, 2e-3, 0], [0, 1, 0], [0, 0, 1]]
    with pytest.raises(UserError, match=r"^--path capture: the stereo calibration in the scene's capture record: "
                                        r"R is not a rotation"):
        capture_camera({"capture": {"stereo": {"calibration_values": data}}}, SceneOptions())
    with pytest.raises(UserError, match=r"^--path capture: the scene's capture record has no camera "
                                        r"\(no 'intrinsics'\)"):
        capture_camera({"capture": {}}, SceneOptions())


def _write_calibration(path: Path, data: dict) -> Path:
    """``data`` (a calibration JSON object) as a JSON file, or for ``.yaml`` as OpenCV FileStorage."""
    if path.suffix == ".json":
        path.write_text(json.dumps(data))
        return path
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", data["image_size"][0])
    fs.write("image_height", data["image_size"][1])
    for key, name in zip(("K_left", "D_left", "K_right", "D_right", "R", "T"), ("K1", "D1", "K2", "D2", "R", "T"),
                         strict=True):
        fs.write(name, np.asarray(data[key], dtype=np.float64).reshape(3, -1) if key[0] in "KR"
                 else np.asarray(data[key], dtype=np.float64).reshape(-1, 1))
    fs.release()
    return path


@pytest.mark.parametrize("name, key", [("calib.json", "K_left"), ("calib.yaml", "K1")])
def test_a_calibration_with_skew_is_refused_naming_the_key(tmp_path, name, key):
    """The camera model has no skew: a K with skew is refused, not silently dropped (the scope's rig dropped it,
    the capture kept it); a skew below 1e-6 fx is taken as none."""
    from rgbd2scene.errors import UserError
    from rgbd2scene.scene.rig import read_scope_calibration

    data = synthetic_calibration()
    data["K_left"] = [[300.0, 0.5, 158.0], [0, 302.0, 121.0], [0, 0, 1]]
    path = _write_calibration(tmp_path / name, data)
    with pytest.raises(ValueError, match=rf"^{key} has skew 0.5, which the camera model does not support$"):
        read_stereo_calibration(path)
    with pytest.raises(UserError, match=rf"^{path}: {key} has skew 0.5, which the camera model does not support$"):
        read_scope_calibration(path)
    data["K_left"][0][1] = 1e-4  # 3.3e-7 fx
    calib = read_stereo_calibration(_write_calibration(tmp_path / name, data))
    assert calib.K_left[0, 1] == 0.0 and calib.to_dict()["K_left"][0][1] == 0.0


def test_the_scene_command_refuses_a_scope_with_skew_in_one_line(tmp_path, capsys):
    from rgbd2scene.cli import main
    from tests.conftest import BUNDLED_SAMPLE

    data = synthetic_calibration()
    data["K_left"] = [[300.0, 0.5, 158.0], [0, 302.0, 121.0], [0, 0, 1]]
    path = _write_calibration(tmp_path / "scope.yaml", data)
    sample = [f"--{key}={BUNDLED_SAMPLE / f'{key}.{ext}'}" for key, ext in (("rgb", "png"), ("depth", "png"),
                                                                           ("camera", "json"))]
    assert main(["scene", *sample, "--scope-calib", str(path), "-o", str(tmp_path / "out")]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert lines == [f"error: {path}: K1 has skew 0.5, which the camera model does not support"]


@pytest.mark.parametrize("size", [4, 5, 8])
def test_an_ideal_lens_is_recorded_as_five_zeros(tmp_path, size):
    """CONVENTIONS section 3: D is "zeros for an ideal pinhole", in every record (the capture's calibration, the
    scope's rig in scene.json, dataset.json's cameras), never [] and in one length."""
    from rgbd2scene.scene.rig import StereoRig, read_scope_calibration
    from rgbd2scene.stages.render import camera_record

    data = synthetic_calibration() | {"D_left": [0.0] * size, "D_right": [0.0] * size}
    path = _write_calibration(tmp_path / "ideal.json", data)
    zeros = [0.0] * 5
    values = read_stereo_calibration(path).to_dict()
    assert values["D_left"] == values["D_right"] == zeros
    rig = read_scope_calibration(path).to_dict()
    assert rig["D"] == rig["right"]["D"] == zeros
    for scope in (StereoRig.endoscope(), StereoRig.from_dict(rig)):
        record = camera_record(scope)
        assert record["left"]["D"] == record["right"]["D"] == zeros


def test_hamlyn_folder_without_a_file_is_named(shared_samples, tmp_path):
    for name in ("calib.left.intrinsic.txt", "calib.left.distortion.txt"):
        (tmp_path / name).write_bytes((shared_samples / HAMLYN / name).read_bytes())
    with pytest.raises(ValueError, match="missing calib.right.intrinsic.txt"):
        read_stereo_calibration(tmp_path, image_size=(360, 288))


# --------------------------------------------------------------------------------------------- rectification


@pytest.mark.parametrize("n_coeffs", DISTORTION_SIZES)
def test_rectification_keeps_the_field_of_view_and_aligns_rows(n_coeffs):
    """Every border pixel of both images lands inside the rectified images (alpha=1; alpha=0 would crop),
    and a 3-D point seen by both cameras lands on one row, at disparity f B / z (rectified left frame)."""
    calib = StereoCalibration.from_dict(synthetic_calibration(n_coeffs))
    rect = rectify(calib)
    R_lr, T_lr = np.asarray(calib.R), np.asarray(calib.T)
    natural = cv2.stereoRectify(calib.K_left, calib.D_left, calib.K_right, calib.D_right, calib.size, R_lr, T_lr,
                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)[2][0, 0]
    assert rect.K[0, 0] >= 0.99 * natural  # the canvas grew instead of down-sampling
    w, h = calib.size
    u, v = pixel_grid(h, w)
    border = np.stack([u, v], -1)[(u == 0) | (v == 0) | (u == w - 1) | (v == h - 1)].reshape(-1, 1, 2)
    for K, D, R, P in ((calib.K_left, calib.D_left, rect.R1, rect.P1), (calib.K_right, calib.D_right, rect.R2,
                                                                       rect.P2)):
        mapped = cv2.undistortPointsIter(border, K, D, R, P, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                                              50, 1e-9)).reshape(-1, 2)
        assert (mapped >= -0.5).all() and (mapped[:, 0] <= rect.width - 0.5).all()
        assert (mapped[:, 1] <= rect.height - 0.5).all()

    rng = np.random.default_rng(n_coeffs)
    points = np.column_stack([rng.uniform(-0.02, 0.02, 50), rng.uniform(-0.015, 0.015, 50), rng.uniform(0.04, 0.1, 50)])
    rvec_right = cv2.Rodrigues(R_lr)[0]
    left_px = cv2.projectPoints(points, np.zeros(3), np.zeros(3), calib.K_left, calib.D_left)[0]
    right_px = cv2.projectPoints(points, rvec_right, T_lr, calib.K_right, calib.D_right)[0]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    lr = cv2.undistortPointsIter(left_px, calib.K_left, calib.D_left, rect.R1, rect.P1, criteria).reshape(-1, 2)
    rr = cv2.undistortPointsIter(right_px, calib.K_right, calib.D_right, rect.R2, rect.P2, criteria).reshape(-1, 2)
    z_rect = (points @ rect.R1.T)[:, 2]
    assert np.abs(lr[:, 1] - rr[:, 1]).max() < 1e-3
    assert np.abs((lr[:, 0] - rr[:, 0]) - rect.K[0, 0] * rect.baseline / z_rect).max() < 1e-3


def test_a_scope_rig_and_its_calibration_have_one_rectified_pair():
    """The rig's rectified pair (CONVENTIONS 1.2: ``render --rectify``, calibration.yaml, evaluation) is the
    capture's at alpha 0 and the rig's size, exactly; an already rectified rig is its own (R = I, P = [K | t]),
    which is what ``cv2.stereoRectify`` gives it too, up to rounding."""
    from rgbd2scene.scene.rig import StereoRig, read_scope_calibration

    rig = read_scope_calibration(Path(__file__).parents[1] / "data_samples" / "scope" / "calibration.yaml")
    calib = rig.calibration
    ours, theirs = calib.rectification(), rectify(calib, alpha=0.0, keep_resolution=False)
    assert not np.allclose(ours.R1, np.eye(3)) and (ours.width, ours.height) == (theirs.width, theirs.height)
    for name in ("R1", "R2", "P1", "P2", "Q"):
        assert np.array_equal(getattr(ours, name), getattr(theirs, name)), name

    rectified = StereoRig.endoscope(64, 32, 60.0, 0.004)
    own = rectified.calibration.rectification()
    opencv = cv2.stereoRectify(rectified.left.K, np.zeros(5), rectified.left.K, np.zeros(5), (64, 32),
                               np.eye(3), np.array([-0.004, 0.0, 0.0]), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    assert np.array_equal(own.R1, np.eye(3)) and np.array_equal(own.P1[:, :3], rectified.left.K)
    for mine, cv in zip((own.R1, own.R2, own.P1, own.P2, own.Q), opencv[:5], strict=True):
        np.testing.assert_allclose(mine, cv, rtol=1e-12, atol=1e-12)



def test_a_calibration_yaml_reads_alike_for_the_dataset_and_the_scope(tmp_path):
    """``calibration.yaml`` has one reader: the realism report's calibration of a raw dataset is the
    calibration of ``--scope-calib``'s rig, and a missing key is named alike."""
    from rgbd2scene.errors import UserError
    from rgbd2scene.scene.rig import read_scope_calibration

    path = Path(__file__).parents[1] / "data_samples" / "scope" / "calibration.yaml"
    calib, rig = read_stereo_calibration(path), read_scope_calibration(path)
    assert rig.calibration == calib and calib.D_left.size == 5
    text = path.read_text()
    start = text.index("D2:")
    (tmp_path / "no_d2.yaml").write_text(text[:start] + text[text.index("R:", start):])
    with pytest.raises(ValueError, match=r"^missing key\(s\) D2 \(a calibration holds"):
        read_stereo_calibration(tmp_path / "no_d2.yaml")
    with pytest.raises(UserError, match=r"no_d2.yaml: missing key\(s\) D2 \(a calibration holds"):
        read_scope_calibration(tmp_path / "no_d2.yaml")


# --------------------------------------------------------------------------------------------- matching


def test_left_right_check_follows_the_disparity_convention():
    """A left pixel (u, v) with disparity d matches the right pixel (u - d, v) (CONVENTIONS section 2)."""
    left = np.full((2, 12), 4.0, np.float32)
    right = np.full((2, 12), 4.0, np.float32)
    right[0, 3] = 9.0  # the match of left (7, 0) disagrees
    right[1, 5] = 4.8  # the match of left (9, 1) agrees within 1 px
    left[1, 2] = np.nan
    ok = left_right_consistent(left, right, 1.0)
    assert not ok[0, 7] and ok[1, 9] and not ok[1, 2]
    assert not ok[:, :4].any()  # u - d < 0: no match inside the right image
    assert ok[0, 4:7].all() and ok[0, 8:].all()


def _slanted_plane_pair(width=240, height=160):
    """A rectified pair of a textured plane with disparity d = 20 + 0.05 u + 0.03 v px, and that disparity."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (height, 2 * width)).astype(np.float32), (0, 0), 1.2)
    texture = cv2.normalize(texture, None, 10, 245, cv2.NORM_MINMAX)
    u, v = pixel_grid(height, width)
    truth = 20.0 + 0.05 * u + 0.03 * v
    left = cv2.remap(texture, (u + width / 2).astype(np.float32), v.astype(np.float32), cv2.INTER_CUBIC)
    # right pixel x sees the left pixel u with u - d(u) = x:  u = (x + 20 + 0.03 v) / 0.95
    src = (u + 20.0 + 0.03 * v) / 0.95
    right = cv2.remap(texture, (src + width / 2).astype(np.float32), v.astype(np.float32), cv2.INTER_CUBIC)
    rgb = [np.repeat(np.clip(im, 0, 255).astype(np.uint8)[..., None], 3, axis=2) for im in (left, right)]
    mask = np.ones((height, width), bool)
    return RectifiedPair(rgb[0], rgb[1], mask, mask.copy()), truth


@pytest.mark.parametrize("matcher", ["sgbm", "elas"])
def test_stereo_depth_of_a_textured_slanted_plane(matcher):
    if matcher == "elas" and not elas_available():
        pytest.skip("pyelas is not installed (optional)")
    pair, truth = _slanted_plane_pair()
    f, baseline = 200.0, 0.005  # disparities 20-36 px: depths 28-50 mm
    result = stereo_depth(pair, f, baseline, StereoOptions(matcher=matcher, min_depth=0.02, max_depth=0.2))
    good = np.isfinite(result.disparity)
    err = np.abs(result.disparity - truth)[good]
    z_err = np.abs(result.depth - f * baseline / truth)[good] / (f * baseline / truth[good])
    print(f"{matcher}: coverage {100 * good.mean():.1f} %, disparity error median {np.median(err):.3f} px, "
          f"p99 {np.percentile(err, 99):.3f} px, depth error median {100 * np.median(z_err):.3f} %")
    # the left columns whose match leaves the right image (u < d) have no depth
    assert not good[:, :20].any()
    assert good[20:-20, 40:-20].mean() > 0.9  # ELAS leaves a band along the image borders unmatched
    assert np.median(err) < 0.15 and np.percentile(err, 99) < 1.0
    # a right image whose data stops half-way leaves the matches into the missing half unconfident
    pair.right_mask[:, 120:] = False
    cut = stereo_depth(pair, f, baseline, StereoOptions(matcher=matcher, min_depth=0.02, max_depth=0.2))
    u = pixel_grid(*truth.shape)[0]
    assert not np.isfinite(cut.disparity)[u - truth > 119].any()


def _sphere_pair(width: int = 425, height: int = 340, f: float = 425.0, baseline: float = 0.0055):
    """A textured sphere of 3 cm radius, its apex 58 mm before the left eye (the Hamlyn phantom's scale), as a
    rectified pair; returns the pair, the true depth, the true unit normals and the pixels on the sphere."""
    radius, apex = 0.03, 0.058
    u, v = pixel_grid(height, width)
    x, y = (u - width / 2) / f, (v - height / 2) / f
    centre, q = apex + radius, x**2 + y**2 + 1
    disc = centre**2 - q * (centre**2 - radius**2)
    on_sphere = disc > 0
    # the near intersection of each pixel's ray (x, y, 1) t with the sphere; beside it a curved backdrop
    z = np.where(on_sphere, (centre - np.sqrt(np.where(on_sphere, disc, 0))) / q, centre / q)
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (height, width)).astype(np.float32), (0, 0), 1.2)
    texture = cv2.normalize(texture, None, 10, 245, cv2.NORM_MINMAX)
    disparity = f * baseline / z
    columns = np.arange(width, dtype=np.float64)
    # right pixel x sees the left pixel s with s - d(s) = x (s - d(s) rises along each row)
    src = np.stack([np.interp(columns, columns - row, columns) for row in disparity])
    right = cv2.remap(texture, src.astype(np.float32), v.astype(np.float32), cv2.INTER_CUBIC)
    rgb = [np.repeat(np.clip(im, 0, 255).astype(np.uint8)[..., None], 3, axis=2) for im in (texture, right)]
    points = np.dstack([x * z, y * z, z])
    normals = np.cross(np.gradient(points, axis=1), np.gradient(points, axis=0))
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    mask = np.ones((height, width), bool)
    return RectifiedPair(rgb[0], rgb[1], mask, mask.copy()), z, normals, on_sphere


def test_the_stereo_smoothing_default_brings_a_curved_surface_closer_than_30_iterations():
    """The default's reason (``STEREO_SMOOTH_ITERATIONS``): stereo depth noise is correlated over the matching
    window, and more iterations than 30 bring both the normals and the depth of a curved surface closer."""
    pair, z, normals, on_sphere = _sphere_pair()
    f, height, width = 425.0, *z.shape
    result = stereo_depth(pair, f, 0.0055, StereoOptions(matcher="sgbm"))
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    mesh, _ = grid_mesh(result.depth, K, pair.left)
    pu, pv = (np.round(f * mesh.vertices[:, i] / mesh.vertices[:, 2] + c).astype(int)
              for i, c in ((0, width / 2), (1, height / 2)))
    # judged on the sphere, seen less obliquely than 60 degrees, 6 px or more from the mesh's rims
    u, v = pixel_grid(height, width)
    rays = np.dstack([u - width / 2, v - height / 2, np.full(z.shape, f)])
    facing = np.abs(np.einsum("ijk,ijk->ij", normals, rays / np.linalg.norm(rays, axis=2, keepdims=True))) > 0.5
    rim = np.zeros(z.shape, bool)
    edge = boundary_vertices(mesh.triangles, mesh.n_vertices)
    rim[pv[edge], pu[edge]] = True
    judged = ((ndimage.distance_transform_edt(~rim) >= 6) & on_sphere & facing)[pv, pu]
    assert judged.sum() > 20000

    def errors(iterations: int) -> tuple[float, float]:
        smoothed, _ = smooth_mesh(mesh, "ray", iterations=iterations)
        depth_um = np.median(np.abs(smoothed.vertices[:, 2] - z[pv, pu])[judged]) * 1e6
        cos = np.abs(np.einsum("ij,ij->i", smoothed.vertex_normals("angle"), normals[pv, pu]))[judged]
        return depth_um, float(np.median(np.degrees(np.arccos(np.clip(cos, 0, 1)))))

    (depth_30, normal_30), (depth_default, normal_default) = errors(30), errors(STEREO_SMOOTH_ITERATIONS)
    print(f"30 iterations: depth {depth_30:.0f} um, normals {normal_30:.2f} deg; default "
          f"({STEREO_SMOOTH_ITERATIONS}): depth {depth_default:.0f} um, normals {normal_default:.2f} deg")
    assert normal_default < 0.7 * normal_30 and depth_default < depth_30


# --------------------------------------------------------------------------------------------- Hamlyn phantom


@pytest.fixture(scope="module")
def hamlyn():
    from tests.conftest import SHARED_SAMPLES

    folder = SHARED_SAMPLES / HAMLYN
    if not folder.is_dir():
        pytest.skip(f"real captures not available: {folder} is absent")
    capture = load_stereo_capture(folder / LEFT, folder / RIGHT, folder, StereoOptions(matcher="sgbm"))
    return folder, capture, reconstruct(capture)


def test_hamlyn_phantom_gives_a_plausible_surface_at_the_calibrated_scale(hamlyn):
    """The phantom heart fills the middle of the view about 6 cm from a 5.5 mm-baseline scope."""
    _, capture, recon = hamlyn
    stats = capture.info["stereo"]["stats"]
    pct = stats["depth_percentiles_m"]
    print(f"coverage {100 * stats['coverage']:.1f} %, depth 5-50-95 %: {pct['5'] * 1e3:.1f} {pct['50'] * 1e3:.1f} "
          f"{pct['95'] * 1e3:.1f} mm, {recon.mesh.n_vertices} vertices")
    assert stats["coverage"] > 0.4
    assert 0.05 < pct["5"] and pct["95"] < 0.1 and 0.055 < pct["50"] < 0.07
    # the surface is closed: every hole enclosed by confident depth is filled
    confident = np.isfinite(capture.depth)
    enclosed = ndimage.binary_fill_holes(confident, np.ones((3, 3))) & ~confident  # holes as 8-connected
    assert enclosed.sum() > 100 and np.isfinite(recon.filled.depth[enclosed]).all()
    z = recon.mesh.vertices[:, 2]
    assert 0.055 < np.median(z) < 0.07
    # nothing is meshed in the rectified image's empty margins
    assert not np.isfinite(recon.filled.depth[~capture.image_mask]).any()


def test_hamlyn_mesh_lies_in_the_unrectified_left_camera(hamlyn):
    """Projected by the original left camera (K, distortion) each vertex lands where its texture came from:
    undistorted and rectified, that point is the vertex's own pixel; and the left image there has its colour."""
    folder, capture, recon = hamlyn
    calib = read_stereo_calibration(folder, image_size=(360, 288))
    rect = rectify(calib)
    mesh = recon.mesh
    projected = cv2.projectPoints(mesh.vertices, np.zeros(3), np.zeros(3), calib.K_left, calib.D_left)[0]
    back = cv2.undistortPoints(projected, calib.K_left, calib.D_left, R=rect.R1, P=rect.P1).reshape(-1, 2)
    rows, cols = np.divmod(mesh.pixels, rect.width)
    offset = np.hypot(back[:, 0] - cols, back[:, 1] - rows)
    assert offset.max() < 1e-3
    # forgetting the rectifying rotation (vertices left in the rectified frame) misses by pixels
    rectified = transform_points(invert_pose(capture.T_world_capture), mesh.vertices)
    wrong = cv2.projectPoints(rectified, np.zeros(3), np.zeros(3), calib.K_left, calib.D_left)[0].reshape(-1, 2)
    assert np.median(np.hypot(*(wrong - projected.reshape(-1, 2)).T)) > 2.0

    left = read_rgb(folder / LEFT).astype(np.float32)
    x, y = projected.reshape(-1, 2).T
    sampled = np.stack([ndimage.map_coordinates(left[..., c], [y, x], order=1) for c in range(3)], axis=-1)
    # (vertices whose pixel lies in a specular highlight take the colour filled in around it, not the capture's)
    captured = ~recon.highlights.ravel()[mesh.pixels]
    err = np.abs(sampled - mesh.vertex_colors)[captured]
    print(f"vertex colour vs the original left image: median {np.median(err):.2f}, p99 {np.percentile(err, 99):.1f} "
          f"({100 * captured.mean():.1f} % of vertices outside highlights)")
    assert np.median(err) < 1.0 and np.percentile(err, 99) < 3.0


def test_hamlyn_render_through_the_capture_camera_reproduces_the_left_image(hamlyn, tmp_path):
    """The Blender scene with the 'as_captured' material, rendered from the capture camera (the rectified left
    camera at its pose T_world_capture in the world), gives back the rectified left image the mesh is textured
    with. A 96x64 window over the heart is rendered (the capture intrinsics shifted to that window), one sample
    through each pixel centre, so rendered pixels and texture pixels correspond one to one."""
    pytest.importorskip("bpy")
    from rgbd2scene.geometry.camera import Intrinsics
    from tests.test_blender_scene import build, describe, render_eyes

    _, capture, recon = hamlyn
    x0, y0, w, h = 170, 150, 96, 64
    intr = capture.intrinsics
    window = Intrinsics(w, h, intr.fx, intr.fy, intr.cx - x0, intr.cy - y0)
    build(describe([capture.T_world_capture], window, "as_captured"), recon.mesh, tmp_path / "scene")
    rendered = render_eyes(tmp_path, exr=False)["left"].astype(int)
    expected = capture.rgb[y0:y0 + h, x0:x0 + w].astype(int)
    covered = np.isfinite(recon.filled.depth[y0:y0 + h, x0:x0 + w])
    covered = cv2.erode(covered.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0  # mesh edges: either side
    err = np.abs(rendered - expected).max(axis=-1)[covered]
    print(f"render vs rectified left image: {covered.sum()} px, mean abs error {err.mean():.3f}, "
          f"{100 * np.mean(err == 0):.2f} % exact")
    assert covered.mean() > 0.9
    assert err.mean() < 0.5 and np.mean(err <= 1) > 0.99


def test_mesh_command_on_the_hamlyn_frame_records_the_stereo_geometry(shared_samples, tmp_path):
    from rgbd2scene.cli import main
    from rgbd2scene.files.meshio import read_ply

    folder = shared_samples / HAMLYN
    out = tmp_path / "mesh"
    assert main(["mesh", "--left", str(folder / LEFT), "--right", str(folder / RIGHT), "--stereo-calib", str(folder),
                 "--matcher", "sgbm", "--no-overview", "-o", str(out)]) == 0
    record = json.loads((out / "scene.json").read_text())
    capture = record["capture"]
    rect = capture["stereo"]["rectification"]
    assert capture["depth_format"] == "stereo" and capture["stereo"]["stats"]["matcher"] == "sgbm"
    assert record["smooth"]["iterations"] == STEREO_SMOOTH_ITERATIONS  # the stereo default
    assert np.allclose(np.array(capture["T_world_capture"])[:3, :3], np.array(rect["R1"]).T)
    assert (capture["width"], capture["height"]) == tuple(rect["image_size"])
    assert np.allclose(capture["intrinsics"]["fx"], rect["K"][0][0])
    texture = read_rgb(out / "mesh_texture.png")
    assert texture.shape == (rect["image_size"][1], rect["image_size"][0], 3)  # the endoscope's own resolution
    mesh = read_ply(out / "mesh.ply")
    assert 0.055 < np.median(mesh.vertices[:, 2]) < 0.07
