"""Reading and validating an RGB-D capture (colour image, depth map, intrinsics).

Depth formats: 16-bit PNG with a depth scale (units per metre), float EXR or ``.npy`` in metres,
raw NYU Kinect PGM (little-endian disparity codes) and SUN RGB-D PNG (bit-rotated uint16).
Everything is returned as float32 metres with NaN for invalid pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.options import OptionError

DEPTH_FORMATS = ("auto", "png", "sun", "nyu", "exr", "npy")
RGB_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".bmp", ".tif", ".tiff")

#: Plausible median depth of a capture, metres (endoscopy at a few cm up to rooms at several m).
MIN_MEDIAN_DEPTH, MAX_MEDIAN_DEPTH = 0.01, 20.0


@dataclass
class Capture:
    """One registered RGB-D frame: uint8 RGB (H, W, 3) and float32 depth in metres (NaN = hole).

    ``T_world_capture`` (4x4) is the pose of the camera the depth is measured in, in the world frame of
    the reconstruction (identity for a plain RGB-D capture; the rectifying rotation undone for a stereo
    frame). ``image_mask`` (bool (H, W), None = every pixel) marks the pixels that hold image data (a
    rectified image has empty margins); nothing outside it is meshed. ``sensor`` is the depth sensor the
    capture names (its camera preset's, ``rgbd2scene.capture.sensors``), None when nothing says.
    """

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    rgb_path: str = ""
    depth_path: str = ""
    depth_format: str = "npy"
    depth_scale: float | None = None
    info: dict = field(default_factory=dict)
    T_world_capture: np.ndarray = field(default_factory=lambda: np.eye(4))
    image_mask: np.ndarray | None = None
    sensor: str | None = None

    @property
    def hole_mask(self) -> np.ndarray:
        return ~np.isfinite(self.depth)

    @property
    def posed(self) -> bool:
        """True when the capture camera is not the world frame."""
        return not np.array_equal(self.T_world_capture, np.eye(4))

    def describe(self) -> dict:
        record = {
            "rgb": self.rgb_path, "depth": self.depth_path, "depth_format": self.depth_format,
            "depth_scale": self.depth_scale, "width": self.intrinsics.width,
            "height": self.intrinsics.height, "intrinsics": self.intrinsics.to_dict(), **self.info,
        }
        if self.posed:
            record["T_world_capture"] = np.asarray(self.T_world_capture).tolist()
        return record


def read_rgb(path: str | Path) -> np.ndarray:
    """Read a colour image as uint8 RGB (H, W, 3); greyscale is expanded, 16-bit is scaled down."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: RGB image not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise UserError(f"{path}: not a readable image (expected PNG, JPEG, PPM or BMP)")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise UserError(f"{path}: unsupported RGB sample type {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[..., :3]
    return np.ascontiguousarray(img[..., ::-1])


def _read_nyu_pgm(path: Path) -> np.ndarray:
    """Raw NYU Kinect PGM: 16-bit little-endian disparity codes despite the PGM header."""
    data = path.read_bytes()
    parts, pos = [], 0
    while len(parts) < 4:  # magic, width, height, maxval, skipping comments
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        parts.append(data[pos:end])
        pos = end
    pos += 1
    if parts[0] != b"P5":
        raise UserError(f"{path}: not a binary PGM (magic {parts[0]!r})")
    w, h, maxval = int(parts[1]), int(parts[2]), int(parts[3])
    if maxval < 256:
        raise UserError(f"{path}: 8-bit PGM cannot hold depth")
    n = w * h
    if len(data) - pos < 2 * n:
        raise UserError(f"{path}: PGM is truncated")
    little = np.frombuffer(data, "<u2", count=n, offset=pos).reshape(h, w)
    return little


def _nyu_codes_to_metres(raw: np.ndarray) -> np.ndarray:
    """NYU toolbox: depth = 351.3 / (1092.5 - raw); raw >= 1084 is invalid."""
    raw = raw.astype(np.float64)
    with np.errstate(divide="ignore"):
        depth = 351.3 / (1092.5 - raw)
    depth[(raw >= 1084) | (depth <= 0)] = np.nan
    return depth.astype(np.float32)


def _sun_unrotate(raw: np.ndarray) -> np.ndarray:
    """SUN RGB-D stores depth in mm rotated by 3 bits: mm = (v >> 3) | (v << 13)."""
    v = raw.astype(np.uint32)
    return ((v >> 3) | (v << 13)) & 0xFFFF


def _looks_like_sun(raw: np.ndarray) -> bool:
    # Depth below 8.192 m rotates to a multiple of 8; plain mm or TUM depth is not so aligned.
    # (--depth-format png overrides this guess; a few distinct levels, as in synthetic data, are no evidence.)
    nz = raw[raw > 0]
    return nz.size > 1000 and float(np.mean(nz % 8 == 0)) > 0.9 and np.unique(nz).size > 100


def read_depth(
    path: str | Path, depth_scale: float | None = None, depth_format: str = "auto"
) -> tuple[np.ndarray, str, float | None]:
    """Read a depth map as float32 metres with NaN holes.

    Parameters
    ----------
    path : depth file (.png, .pgm, .exr, .npy, ...).
    depth_scale : units per metre for integer depth (1000 for mm PNGs, 5000 for TUM); default 1000.
    depth_format : one of ``DEPTH_FORMATS``; ``auto`` decides from the suffix and the values.

    Returns
    -------
    depth, format actually used, depth scale actually used (None for metric float formats).
    """
    path = Path(path)
    if depth_format not in DEPTH_FORMATS:
        raise OptionError("depth_format", f"unknown format {depth_format!r}; choose one of {', '.join(DEPTH_FORMATS)}")
    if not path.is_file():
        raise UserError(f"{path}: depth file not found")
    suffix = path.suffix.lower()
    fmt = depth_format
    if fmt == "auto":
        fmt = {".npy": "npy", ".exr": "exr"}.get(suffix, "png")

    if fmt == "npy":
        try:
            depth = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise UserError(f"{path}: not a readable .npy array ({exc})") from None
        if not np.issubdtype(depth.dtype, np.floating):
            raise UserError(f"{path}: .npy depth must be float metres, got {depth.dtype}")
        return _floats_to_metres(path, _squeeze_depth(path, depth)), "npy", None
    if fmt == "exr":
        img = _read_exr(path)
        if img is None:
            raise UserError(f"{path}: not a readable EXR depth image")
        return _floats_to_metres(path, _squeeze_depth(path, img)), "exr", None

    if fmt == "nyu" or (depth_format == "auto" and suffix == ".pgm"):
        raw = _read_nyu_pgm(path)
        if fmt == "nyu" or raw.max() <= 2047:  # 11-bit Kinect disparity codes
            return _nyu_codes_to_metres(raw), "nyu", None
        raw = raw.byteswap()  # a standard (big-endian) 16-bit PGM of depth units
        fmt = "png"
    else:
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if raw is None:
            raise UserError(f"{path}: not a readable depth image")
        raw = _squeeze_depth(path, raw)
        if raw.dtype.kind == "f":
            return _floats_to_metres(path, raw), "float", None
        if raw.dtype != np.uint16:
            raise UserError(f"{path}: depth image must be 16-bit (got {raw.dtype}); an 8-bit image holds no depth")
        if fmt == "sun" or (depth_format == "auto" and _looks_like_sun(raw)):
            raw, fmt = _sun_unrotate(raw), "sun"
    scale = 1000.0 if depth_scale is None else float(depth_scale)
    if not (scale > 0 and np.isfinite(scale)):
        raise OptionError("depth_scale", f"must be a positive number, got {depth_scale}")
    depth = raw.astype(np.float32) / np.float32(scale)
    depth[raw == 0] = np.nan
    return depth, fmt, scale


def _read_exr(path: Path) -> np.ndarray | None:
    """An EXR's depth as float32 (H, W) — its ``Z``/``depth``/``Y`` channel — or its colour channels stacked
    (H, W, C) for :func:`_squeeze_depth` to judge; None when the file is not a readable EXR. Read with the
    OpenEXR package (OpenCV's EXR reader needs a process-wide switch)."""
    import OpenEXR

    try:
        channels = {name: ch.pixels for name, ch in OpenEXR.File(str(path), separate_channels=True).channels().items()}
    except Exception:  # noqa: BLE001 - any unreadable file is a user error
        return None
    for name in ("Z", "depth", "Y"):
        if name in channels:
            return np.asarray(channels[name], dtype=np.float32)
    colour = [channels[c] for c in ("R", "G", "B") if c in channels] or list(channels.values())
    if not colour:
        return None
    return np.stack([np.asarray(c, dtype=np.float32) for c in colour], axis=-1)


def _squeeze_depth(path: Path, arr: np.ndarray) -> np.ndarray:
    """The single channel of a depth image. Colour images are refused even when their channels agree:
    depth is one channel, and a 3- or 4-channel file is almost always a colour image given by mistake."""
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        raise UserError(f"{path}: depth must be a single-channel image, got {arr.shape[2]} channels "
                        "(a colour image?)")
    if arr.ndim != 2:
        raise UserError(f"{path}: depth must be a single-channel image, got shape {arr.shape}")
    return arr


def _floats_to_metres(path: Path, depth: np.ndarray) -> np.ndarray:
    """Float depth in metres; 0 marks a hole. NaN, infinite or negative values are rejected:
    they hide a unit or sign error (write 0 for missing depth)."""
    depth = np.asarray(depth, dtype=np.float32)
    if not np.isfinite(depth).all():
        raise UserError(f"{path}: depth contains NaN or infinite values (write 0 for missing depth)")
    if (depth < 0).any():
        raise UserError(f"{path}: depth contains negative values (min {depth.min():.4g} m); depth must be >= 0")
    depth = depth.copy()
    depth[depth == 0] = np.nan
    return depth


def validate_depth(depth: np.ndarray, path: str, scale: float | None) -> None:
    """Raise ``UserError`` for empty depth or a scale that makes the scene implausible."""
    if depth.size == 0:
        raise UserError(f"{path}: depth image is empty")
    valid = np.isfinite(depth)
    if not valid.any():
        raise UserError(f"{path}: depth has no valid pixel (all zero or invalid)")
    median = float(np.median(depth[valid]))
    if MIN_MEDIAN_DEPTH <= median <= MAX_MEDIAN_DEPTH:
        return
    hint = ""
    if scale is not None:
        raw_median = median * scale
        fits = [s for s in (1.0, 100.0, 1000.0, 5000.0, 10000.0, 100000.0)
                if MIN_MEDIAN_DEPTH <= raw_median / s <= MAX_MEDIAN_DEPTH]
        if fits:
            best = min(fits, key=lambda s: abs(np.log(raw_median / s / 0.5)))
            hint = f"; a depth scale of {best:g} would give {raw_median / best:.3g} m"
        hint = f" with depth scale {scale:g}{hint}"
    raise UserError(
        f"{path}: implausible median depth {median:.4g} m{hint} "
        f"(expected {MIN_MEDIAN_DEPTH}-{MAX_MEDIAN_DEPTH} m)"
    )


def load_capture(
    rgb_path: str | Path,
    depth_path: str | Path,
    intrinsics: Intrinsics,
    depth_scale: float | None = None,
    depth_format: str = "auto",
    sensor: str | None = None,
) -> Capture:
    """Read and validate one RGB-D capture; every problem with the files is a one-line ``UserError`` naming the
    file (a bad ``depth_format`` or ``depth_scale`` value: an ``OptionError``). ``sensor``: the depth sensor the
    capture names, if any."""
    rgb = read_rgb(rgb_path)
    depth, fmt, scale = read_depth(depth_path, depth_scale, depth_format)
    if rgb.shape[:2] != depth.shape:
        raise UserError(
            f"{depth_path}: depth is {depth.shape[1]}x{depth.shape[0]} but RGB {rgb_path} is "
            f"{rgb.shape[1]}x{rgb.shape[0]}; they must be registered at the same size"
        )
    if (intrinsics.width, intrinsics.height) != (depth.shape[1], depth.shape[0]):
        raise UserError(
            f"intrinsics are for {intrinsics.width}x{intrinsics.height} but {depth_path} is "
            f"{depth.shape[1]}x{depth.shape[0]}"
        )
    intrinsics.check("intrinsics")
    validate_depth(depth, str(depth_path), scale)
    return Capture(rgb, depth, intrinsics, str(rgb_path), str(depth_path), fmt, scale, sensor=sensor)

