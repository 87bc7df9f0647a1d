"""``rgbd2scene realism``: each measure on images with a known answer, stereo difficulty on a fake matcher with
exact figures, the CLI on the synthetic plane dataset (table, JSON, picture), and bad inputs."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from rgbd2scene.capture.stereo import read_stereo_calibration
from rgbd2scene.cli import main
from rgbd2scene.dataset import Dataset
from rgbd2scene.files.images import read_image, write_image
from rgbd2scene.groundtruth.synthetic import write_plane_dataset
from rgbd2scene.realism import measures as m
from rgbd2scene.realism import stereo
from rgbd2scene.realism.report import Row


def smooth_image(h: int = 128, w: int = 160) -> np.ndarray:
    """Grey (as RGB, float 0-255): a ramp plus slow waves, no detail at the pixel scale."""
    y, x = np.mgrid[0:h, 0:w].astype(float)
    grey = 80 + 0.3 * x + 20 * np.sin(x / 9.0) * np.cos(y / 13.0)
    return np.repeat(grey[..., None], 3, axis=2)


def textured_image(seed: int = 0, h: int = 128, w: int = 160) -> np.ndarray:
    """Grey (as RGB, float): smoothed white noise, detail down to a few pixels."""
    rng = np.random.default_rng(seed)
    grey = cv2.GaussianBlur(rng.normal(0, 40, (h, w)), (0, 0), 1.0) + 120
    return np.repeat(grey[..., None], 3, axis=2)


# ------------------------------------------------------------------------------------------------ measures


@pytest.mark.parametrize("sigma", [2.0, 5.0, 10.0])
def test_noise_sigma_finds_added_gaussian_noise(sigma):
    rng = np.random.default_rng(1)
    clean = smooth_image()
    noisy = clean + rng.normal(0, sigma, clean.shape[:2])[..., None]  # the same noise in R, G, B: luma noise sigma
    assert m.noise_sigma(noisy) == pytest.approx(sigma, rel=0.15)
    # an independent estimator agrees: Immerkaer (1996), the mean |Laplacian-difference| of the image
    grey = m.luminance(noisy)
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], float)
    response = cv2.filter2D(grey, -1, kernel)[1:-1, 1:-1]
    immerkaer = math.sqrt(math.pi / 2) * np.abs(response).mean() / 6
    assert m.noise_sigma(noisy) == pytest.approx(immerkaer, rel=0.15)
    assert m.noise_sigma(clean) < 0.1 * sigma


def test_noise_sigma_measures_only_the_mask():
    rng = np.random.default_rng(2)
    image = smooth_image()
    image[:, :80] += rng.normal(0, 2.0, (128, 80))[..., None]
    image[:, 80:] += rng.normal(0, 8.0, (128, 80))[..., None]
    left = np.zeros(image.shape[:2], bool)
    left[:, :80] = True
    assert m.noise_sigma(image, left) == pytest.approx(2.0, rel=0.15)
    assert m.noise_sigma(image, ~left) == pytest.approx(8.0, rel=0.15)


def test_blur_lowers_sharpness():
    sharp = textured_image()
    blurred = cv2.GaussianBlur(sharp, (0, 0), 2.0)
    assert m.high_frequency_share(blurred) < 0.2 * m.high_frequency_share(sharp)
    assert m.gradient_mean(blurred) < 0.6 * m.gradient_mean(sharp)
    # exposure does not count: a darker copy is exactly as sharp
    assert m.high_frequency_share(0.5 * sharp) == pytest.approx(m.high_frequency_share(sharp), rel=1e-9)
    assert m.gradient_mean(0.5 * sharp) == pytest.approx(m.gradient_mean(sharp), rel=1e-9)


def test_darkening_halves_brightness_and_keeps_contrast_and_colour():
    rng = np.random.default_rng(3)
    image = rng.uniform(20, 230, (40, 50, 3))
    dark = 0.5 * image
    assert m.brightness(dark) == pytest.approx(0.5 * m.brightness(image), rel=1e-12)
    assert m.brightness(image) == pytest.approx(np.mean(image @ [0.2126, 0.7152, 0.0722]), rel=1e-12)
    assert m.rms_contrast(dark) == pytest.approx(m.rms_contrast(image), rel=1e-12)
    np.testing.assert_allclose(m.chromaticity(dark), m.chromaticity(image), rtol=1e-12)


def test_colour_measures_known_values():
    image = np.zeros((10, 10, 3))
    image[...] = (100, 50, 50)
    np.testing.assert_allclose(m.chromaticity(image), [0.5, 0.25, 0.25])
    assert m.mean_saturation(image) == pytest.approx(0.5)
    assert m.mean_saturation(np.full((4, 4, 3), 90.0)) == 0.0


def test_highlight_share_counts_near_white_pixels_in_the_mask():
    image = np.full((20, 20, 3), 120, np.uint8)
    image[:2, :] = 255  # 10 % white
    image[2:4, :] = (255, 200, 200)  # bright but saturated (0.22): not a highlight core
    assert m.highlight_share(image) == pytest.approx(0.10)
    mask = np.zeros((20, 20), bool)
    mask[:4, :] = True
    assert m.highlight_share(image, mask) == pytest.approx(0.5)


def test_empty_or_misshaped_mask_is_an_error():
    image = smooth_image(16, 16)
    with pytest.raises(ValueError, match="no pixel"):
        m.brightness(image, np.zeros((16, 16), bool))
    with pytest.raises(ValueError, match="shape"):
        m.brightness(image, np.ones((8, 16), bool))


def test_ratio_of_a_row():
    band = (0.8, 1.25)
    assert Row("x", "left", "", 2.0, 2.4, band).ratio == pytest.approx(1.2)
    assert Row("x", "left", "", 2.0, 2.4, band).within
    assert not Row("x", "left", "", 2.0, 2.6, band).within
    assert Row("x", "left", "", 0.0, 0.0, band).ratio == 1.0
    assert math.isinf(Row("x", "left", "", 0.0, 0.1, band).ratio)


# ------------------------------------------------------------------------------------------------ stereo


class ConstantMatcher:
    """A 'stereo method' answering ``value`` px everywhere (for both the pair and the mirrored pair)."""

    name = "constant"

    def __init__(self, value: float):
        self.value = value

    def __call__(self, index, left, right):
        return np.full(left.shape[:2], self.value, np.float32)


def test_stereo_scores_of_a_constant_matcher_are_exact():
    h, w = 12, 40
    left = right = np.zeros((h, w, 3), np.uint8)
    gt = np.full((h, w), 4.0)
    gt[:, :10] = np.nan
    score = stereo.score_pair(ConstantMatcher(5.0), left, right, gt_disparity=gt)
    assert score.density == 1.0
    # a left pixel u matches right u - 5, inside the image for u >= 5, where the right view agrees (5 px)
    assert score.lr_consistency == pytest.approx((w - 5) / w)
    assert score.epe == pytest.approx(1.0) and score.bad2 == 0.0
    mask = np.zeros((h, w), bool)
    mask[:, :20] = True
    assert stereo.score_pair(ConstantMatcher(5.0), left, right, mask).lr_consistency == pytest.approx(15 / 20)


def test_lr_consistency_catches_disagreeing_matches():
    d_left = np.full((2, 10), 2.0)
    d_right = np.full((2, 10), 2.0)
    d_right[0, :] = 4.0  # row 0: the right view points elsewhere
    ok = stereo.lr_consistent(d_left, d_right)
    assert not ok[0].any()
    assert ok[1, 2:].all() and not ok[1, :2].any()  # u - d < 0 leaves the image


def test_calibration_yaml_reads_back(tmp_path):
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 15.5], [0, 0, 1]])
    path = tmp_path / "calibration.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in {"K1": K, "D1": np.zeros((1, 5)), "K2": K, "D2": np.zeros((1, 5)), "R": np.eye(3),
                       "T": np.array([[-0.005], [0.0], [0.0]])}.items():
        fs.write(key, value)
    fs.write("image_width", 64)
    fs.write("image_height", 32)
    fs.release()
    calib = read_stereo_calibration(path)
    np.testing.assert_array_equal(calib.K_left, K)
    assert calib.baseline == pytest.approx(0.005) and calib.size == (64, 32)


# ------------------------------------------------------------------------------------------------ the command


@pytest.fixture(scope="module")
def plane(tmp_path_factory):
    return Dataset(write_plane_dataset(tmp_path_factory.mktemp("realism") / "ds", 2))


def _real_pair(plane: Dataset, folder, transform=lambda img, eye: img):
    paths = []
    for eye in ("left", "right"):
        path = folder / f"real_{eye}.png"
        write_image(path, transform(plane.rgb(eye, 0), eye))
        paths.append(str(path))
    return paths


def test_cli_same_frames_give_ratio_one_and_write_table_json_picture(plane, tmp_path, capsys):
    left, right = _real_pair(plane, tmp_path)
    out = tmp_path / "out"
    assert main(["realism", str(plane.root), "--real", left, right, "--methods", "sgbm", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| brightness | left |" in printed and "SGBM density" in printed
    report = json.loads((out / "realism.json").read_text())
    measures = {r["measure"] for r in report["rows"]}
    assert {"brightness", "contrast", "noise sigma", "high-frequency share", "highlight share",
            "SGBM density", "SGBM LR consistency"} <= measures
    assert {r["eye"] for r in report["rows"] if r["measure"] == "brightness"} == {"left", "right"}
    for row in report["rows"]:
        assert row["ratio"] == pytest.approx(1.0, abs=1e-9), row
        assert row["within"]
    assert report["misses"] == 0
    assert "| brightness | left |" in (out / "realism.md").read_text()
    picture = read_image(out / "realism.png")
    assert picture is not None and picture.shape[0] > 2 * plane.height and picture.shape[1] >= 4 * 256


def test_cli_darker_real_frame_shows_in_the_ratio(plane, tmp_path, capsys):
    left, right = _real_pair(plane, tmp_path, lambda img, eye: (img // 2).astype(np.uint8))
    assert main(["realism", str(plane.root), "--real", left, right, "--methods", "none",
                 "-o", str(tmp_path / "o")]) == 0
    rows = json.loads((tmp_path / "o" / "realism.json").read_text())["rows"]
    bright = [r for r in rows if r["measure"] == "brightness"]
    assert len(bright) == 2
    for r in bright:
        assert r["ratio"] == pytest.approx(2.0, rel=0.02) and not r["within"]
    assert "MISS" in capsys.readouterr().out
    assert not any(r["measure"].startswith("SGBM") for r in rows)


def test_cli_real_disparity_adds_error_rows(plane, tmp_path):
    left, right = _real_pair(plane, tmp_path)
    disparity = tmp_path / "disparity.npy"
    np.save(disparity, plane.gt("left", 0, ("disparity",))["disparity"])
    out = tmp_path / "o"
    assert main(["realism", str(plane.root), "--real", left, right, "--real-disparity", str(disparity),
                 "--methods", "sgbm", "-o", str(out)]) == 0
    rows = {r["measure"]: r for r in json.loads((out / "realism.json").read_text())["rows"]}
    assert rows["SGBM EPE"]["real"] == rows["SGBM EPE"]["render"]
    assert 0 < rows["SGBM EPE"]["real"] < 1.0  # SGBM matches the textured plane to a fraction of a pixel
    assert "SGBM bad-2" in rows


def test_cli_mask_and_surface_only_choose_the_pixels(plane, tmp_path):
    surface = np.isfinite(plane.gt("left", 0, ("depth",))["depth"])
    assert 0.2 < surface.mean() < 0.95  # the plane ends inside the view: background beyond

    def whiten_background(img, eye):
        seen = np.isfinite(plane.gt(eye, 0, ("depth",))["depth"])
        img = img.copy()
        img[~seen] = 255
        return img

    left, _ = _real_pair(plane, tmp_path, whiten_background)

    def brightness_ratio(*extra) -> float:
        out = tmp_path / f"o{len(extra)}"
        assert main(["realism", str(plane.root), "--real", left, "-o", str(out), *extra]) == 0
        rows = json.loads((out / "realism.json").read_text())["rows"]
        return next(r["ratio"] for r in rows if r["measure"] == "brightness")

    assert brightness_ratio() < 0.8
    assert brightness_ratio("--surface-only") == pytest.approx(1.0)
    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), np.where(surface, 255, 0).astype(np.uint8))
    assert brightness_ratio("--real-mask", str(mask), "--frame", "0") == pytest.approx(1.0)


def test_real_frame_of_another_size_is_an_error_and_writes_nothing(plane, tmp_path, capsys):
    small = tmp_path / "small.png"
    write_image(small, np.zeros((plane.height // 2, plane.width // 2, 3), np.uint8))
    out = tmp_path / "out"
    assert main(["realism", str(plane.root), "--real", str(small), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "small.png" in err[0]
    assert f"{plane.width // 2}x{plane.height // 2}" in err[0] and f"{plane.width}x{plane.height}" in err[0]
    assert not out.exists()


@pytest.mark.parametrize("case, message", [
    ("missing", "not found"), ("mask_size", "mask is"), ("three", "--real takes"), ("frame", "no rendered frame"),
    ("disparity_mono", "needs the right image"), ("method", "unknown method"),
])
def test_bad_inputs_exit_2(plane, tmp_path, capsys, case, message):
    left, right = _real_pair(plane, tmp_path)
    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), np.full((5, 5), 255, np.uint8))
    args = {"missing": ["--real", str(tmp_path / "nope.png")],
            "mask_size": ["--real", left, "--real-mask", str(mask)],
            "three": ["--real", left, right, left],
            "frame": ["--real", left, "--frame", "7"],
            "disparity_mono": ["--real", left, "--real-disparity", str(tmp_path / "d.npy")],
            "method": ["--real", left, right, "--methods", "sgbm,bm"]}[case]
    assert main(["realism", str(plane.root), *args, "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0]
    assert not (tmp_path / "out").exists()


def sgbm_for(plane: Dataset):
    from rgbd2scene.evaluate.methods import DisparityRange, Sgbm

    z = plane.gt("left", 0, ("depth",))["depth"]
    return Sgbm(DisparityRange.from_depths(float(np.nanmin(z)), float(np.nanmax(z)), plane.fx, plane.baseline))


def test_raw_dataset_is_rectified_with_its_calibration(plane, tmp_path):
    import shutil

    raw = tmp_path / "raw"
    shutil.copytree(plane.root, raw)
    meta = json.loads((raw / "dataset.json").read_text())
    meta["camera"] = {**(meta.get("camera") or {}), "rectified": False}
    (raw / "dataset.json").write_text(json.dumps(meta))
    fs = cv2.FileStorage(str(raw / "calibration.yaml"), cv2.FILE_STORAGE_WRITE)
    for key, value in {"K1": plane.K, "D1": np.zeros((1, 5)), "K2": plane.K, "D2": np.zeros((1, 5)), "R": np.eye(3),
                       "T": np.array([[-plane.baseline], [0.0], [0.0]])}.items():
        fs.write(key, value)
    fs.write("image_width", plane.width)
    fs.write("image_height", plane.height)
    fs.release()
    left, right = _real_pair(plane, tmp_path)
    disparity = tmp_path / "disparity.npy"
    np.save(disparity, plane.gt("left", 0, ("disparity",))["disparity"])
    out = tmp_path / "o"
    assert main(["realism", str(raw), "--real", left, right, "--real-disparity", str(disparity),
                 "--methods", "sgbm", "-o", str(out)]) == 0
    report = json.loads((out / "realism.json").read_text())
    assert any("raw dataset" in n for n in report["notes"])
    assert any("calibration.yaml" in n for n in report["notes"] if n.startswith("real pair"))
    rows = {r["measure"]: r for r in report["rows"]}
    assert "SGBM EPE" not in rows  # no ground-truth disparity in the rectified grid of a raw dataset
    # both pairs went through the same rectification: the same figures; and an already rectified rig
    # matches about as densely as without it
    assert rows["SGBM density"]["ratio"] == pytest.approx(1.0)
    direct = stereo.score_pair(sgbm_for(plane), plane.rgb("left", 0), plane.rgb("right", 0),
                               np.ones((plane.height, plane.width), bool))
    assert rows["SGBM density"]["render"] == pytest.approx(direct.density, abs=0.1)
