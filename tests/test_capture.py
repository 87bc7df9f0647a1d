import cv2
import numpy as np
import pytest

from rgbd2scene.capture.camera import preset
from rgbd2scene.capture.readers import load_capture, read_depth, read_rgb
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Intrinsics

INTR = Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)


def _write_pair(tmp_path, depth_mm=None, rgb_shape=(48, 64)):
    rgb = np.random.default_rng(0).integers(0, 255, (*rgb_shape, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "rgb.png"), rgb)
    if depth_mm is None:
        depth_mm = np.full((48, 64), 600, np.uint16)
    cv2.imwrite(str(tmp_path / "depth.png"), depth_mm)
    return tmp_path / "rgb.png", tmp_path / "depth.png"


def test_png_depth_scale_and_holes(tmp_path):
    d = np.full((48, 64), 600, np.uint16)
    d[0, :] = 0
    rgb, depth = _write_pair(tmp_path, d)
    cap = load_capture(rgb, depth, INTR, depth_scale=1000)
    assert cap.depth.dtype == np.float32 and np.isclose(np.nanmedian(cap.depth), 0.6)
    assert np.isnan(cap.depth[0]).all() and np.isfinite(cap.depth[1:]).all()
    assert cap.rgb.shape == (48, 64, 3) and cap.rgb.dtype == np.uint8


def test_rgb_channel_order(tmp_path):
    img = np.zeros((4, 4, 3), np.uint8)
    img[..., 2] = 255  # red in OpenCV's BGR order
    cv2.imwrite(str(tmp_path / "red.png"), img)
    assert (read_rgb(tmp_path / "red.png")[..., 0] == 255).all()


def test_npy_and_exr_metres(tmp_path):
    z = np.full((48, 64), 0.05, np.float32)
    z[3, 3] = 0.0
    np.save(tmp_path / "d.npy", z)
    d, fmt, scale = read_depth(tmp_path / "d.npy")
    assert fmt == "npy" and scale is None and np.isnan(d[3, 3]) and np.isclose(d[0, 0], 0.05)
    import OpenEXR

    header = {"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION}
    for channels in ({"Y": z}, {"Z": z}):  # grey (as OpenCV writes it), a depth channel
        OpenEXR.File(header, channels).write(str(tmp_path / "d.exr"))
        d2, fmt2, _ = read_depth(tmp_path / "d.exr")
        assert fmt2 == "exr" and np.allclose(d, d2, equal_nan=True)
    OpenEXR.File(header, {"R": z, "G": z, "B": z}).write(str(tmp_path / "d.exr"))  # a colour EXR given as depth
    with pytest.raises(UserError, match="single-channel"):
        read_depth(tmp_path / "d.exr")


@pytest.mark.parametrize(
    "setup, message",
    [
        ("missing_rgb", "RGB image not found"),
        ("bad_rgb", "not a readable image"),
        ("missing_depth", "depth file not found"),
        ("size_mismatch", "must be registered at the same size"),
        ("all_invalid", "no valid pixel"),
        ("nan_npy", "NaN or infinite"),
        ("negative_npy", "negative values"),
        ("scale_too_small", "a depth scale of 1000 would give"),
        ("eight_bit", "must be 16-bit"),
        ("intrinsics_size", "intrinsics are for"),
    ],
)
def test_bad_input_names_file_and_problem(tmp_path, setup, message):
    rgb, depth = _write_pair(tmp_path)
    intr, scale = INTR, 1000
    if setup == "missing_rgb":
        rgb = tmp_path / "nope.png"
    elif setup == "bad_rgb":
        rgb.write_bytes(b"not an image")
    elif setup == "missing_depth":
        depth = tmp_path / "nope.png"
    elif setup == "size_mismatch":
        rgb, _ = _write_pair(tmp_path, rgb_shape=(40, 64))
    elif setup == "all_invalid":
        cv2.imwrite(str(depth), np.zeros((48, 64), np.uint16))
    elif setup in ("nan_npy", "negative_npy"):
        z = np.full((48, 64), 0.5, np.float32)
        z[0, 0] = np.nan if setup == "nan_npy" else -1.0
        depth = tmp_path / "d.npy"
        np.save(depth, z)
    elif setup == "scale_too_small":
        scale = 1.0  # millimetre PNG read as metres: median 600 m
    elif setup == "eight_bit":
        cv2.imwrite(str(depth), np.full((48, 64), 60, np.uint8))
    elif setup == "intrinsics_size":
        intr = preset("primesense")
    with pytest.raises(UserError, match=message) as info:
        load_capture(rgb, depth, intr, depth_scale=scale)
    text = str(info.value)
    assert "\n" not in text
    if setup not in ("intrinsics_size",):
        assert any(str(p) in text for p in (rgb, depth))


def test_real_captures_parse_to_plausible_ranges(shared_samples):
    s = shared_samples
    cases = [
        (s / "tum_office_frame_open3d/TUM_depth.png", 5000, "png", (1.0, 10.0), (0.15, 0.25)),
        (s / "nyu_sun_raw_frames_open3d/NYU_depth.pgm", None, "nyu", (0.5, 8.0), (0.05, 0.10)),
        (s / "nyu_sun_raw_frames_open3d/SUN_depth.png", None, "sun", (0.5, 10.0), (0.15, 0.22)),
        (s / "redwood_livingroom1_5frames_open3d/depth/00000.png", 1000, "png", (0.9, 2.8), (0.10, 0.16)),
    ]
    for path, scale, fmt, (lo, hi), (hole_lo, hole_hi) in cases:
        depth, used_fmt, _ = read_depth(path, scale)
        assert used_fmt == fmt, path
        valid = np.isfinite(depth)
        assert lo <= np.nanmin(depth) and np.nanmax(depth) <= hi, path
        assert hole_lo <= 1 - valid.mean() <= hole_hi, path
    cap = load_capture(s / "tum_office_frame_open3d/TUM_color.png", s / "tum_office_frame_open3d/TUM_depth.png",
                       preset("primesense"), depth_scale=5000)
    assert cap.rgb.shape == (480, 640, 3)


@pytest.mark.parametrize("channels", [3, 4])
def test_colour_depth_is_refused_even_with_equal_channels(tmp_path, channels):
    grey = np.full((48, 64), 0.6, np.float32)
    np.save(tmp_path / "depth.npy", np.dstack([grey] * channels))
    with pytest.raises(UserError, match=f"depth.npy: depth must be a single-channel image, got {channels} channels"):
        read_depth(tmp_path / "depth.npy")
    np.save(tmp_path / "one.npy", grey[..., None])  # an explicit single channel is fine
    assert read_depth(tmp_path / "one.npy")[0].shape == (48, 64)
