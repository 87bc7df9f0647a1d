"""A stereo endoscope frame as an RGB-D capture: calibration, rectification, stereo matching, confident depth.

Calibration (:class:`~rgbd2scene.geometry.stereo.StereoCalibration`, OpenCV conventions: each eye's K and D in
any of OpenCV's models, and the left-to-right ``R``, ``T`` in metres, ``X_right = R X_left + T``):
:func:`read_stereo_calibration` is the one reader of a calibration file. It takes an OpenCV FileStorage file
(``K1 D1 K2 D2 R T``, ``image_width``, ``image_height``: a dataset's ``calibration.yaml``, what
``cv2.stereoCalibrate`` users save), a JSON file (``K_left, D_left, K_right, D_right, R, T`` and the image size
as ``image_size: [w, h]`` or ``width``/``height``) or a folder laid out like the Hamlyn data
(``calib.{left,right}.intrinsic.txt`` 3x3, ``calib.{left,right}.distortion.txt``, ``calib.l2r.4x4`` in mm; the
image size then comes from the images); all of them end in the one validation,
:meth:`~rgbd2scene.geometry.stereo.StereoCalibration.from_matrices`.

Rectification (:func:`rectify`, through :func:`~rgbd2scene.geometry.rectification.stereo_rectification`, the
one definition of a rig's rectified pair) uses ``alpha=1``: every pixel of both source images stays in the
rectified images (alpha=0 would crop the field of view to the pixels valid in both; the margins alpha=1 leaves
are marked by ``image_mask`` and never meshed). With ``keep_resolution`` the
rectified canvas grows until its focal length reaches the one ``stereoRectify`` picks without scaling
(the mean fy of the two cameras for a horizontal pair), so no part of the image is down-sampled.

Depth (:func:`stereo_depth`): SGBM (OpenCV) or ELAS (``pyelas``, used by ``matcher="auto"`` when
``import elas`` works), over the disparities of the expected depth range ``[min_depth, max_depth]``;
then only confident pixels are kept: left-right consistency (the right view's disparity at the matched
pixel agrees within ``max_lr_difference`` px), texture (grey-level standard deviation in the matching
window at least ``min_texture_std``; saturated highlights, whose position depends on the viewpoint,
count as untextured) and speckles (connected disparity regions smaller than ``speckle_fraction`` of the
image, and structures thinner than 3 px, are dropped). Depth is z = f B / d in the rectified left camera
(``conventions.depth_from_disparity``).

:func:`load_stereo_capture` turns a frame into a :class:`~rgbd2scene.capture.readers.Capture` of the
rectified left image, the confident depth (NaN elsewhere) and the rectified intrinsics, with
``T_world_capture`` = the rectified camera's pose in the calibration's left camera frame (rotation R1^T),
so the usual reconstruction fills and meshes it and returns the mesh in the left camera frame.
"""

from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rgbd2scene.capture.readers import Capture, read_rgb
from rgbd2scene.conventions import depth_from_disparity
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.geometry.rectification import Rectification, stereo_rectification
from rgbd2scene.geometry.stereo import StereoCalibration

#: Files of a Hamlyn-style calibration folder.
HAMLYN_FILES = {"K_left": "calib.left.intrinsic.txt", "D_left": "calib.left.distortion.txt",
                "K_right": "calib.right.intrinsic.txt", "D_right": "calib.right.distortion.txt",
                "l2r_mm": "calib.l2r.4x4"}
#: Keys of an OpenCV FileStorage stereo calibration (CONVENTIONS section 2's ``calibration.yaml``, what
#: ``scene --scope-calib`` reads): the matrices, then the image size.
OPENCV_CALIB_KEYS = ("K1", "D1", "K2", "D2", "R", "T")
OPENCV_SIZE_KEYS = ("image_width", "image_height")
OPENCV_SUFFIXES = (".yaml", ".yml", ".xml")
MATCHERS = ("auto", "sgbm", "elas")
#: Ray-smoothing iterations for a stereo frame's mesh (10 for RGB-D). Stereo depth is rough at the pixel
#: scale (sub-pixel disparity noise of 0.07-0.14 px is about one pixel footprint in depth), and the noise is
#: correlated over the matching window, a few pixels: 30 iterations left lumps 3-8 px across that the render
#: shades as glints the real Hamlyn phantom does not show (the digital twin's gradient mean 1.41 times the real
#: frame's; 1.16 at 100; ``benchmarks/results/twin.md``). On a textured sphere of 3 cm radius 6 cm away
#: (``tests/test_stereo.py``, the surface seen less obliquely than 60 degrees), 30 -> 100 iterations cut the
#: median normal error from 5.6 to 2.8 degrees with SGBM (ELAS 7.8 to 3.0) and the median depth error from 86
#: to 64 um (ELAS 134 to 109); 150 raises the depth error again. On the Hamlyn phantom 10 iterations left
#: 0.5 % of the pixels failing ``verify``'s left-right check, 30 none; at 100 the mesh lies 0.24 mm (median;
#: 95th percentile 0.83 mm) from the unsmoothed stereo depth, against 0.15 / 0.50 mm at 30. Relief a few
#: pixels across is flattened with the noise.
STEREO_SMOOTH_ITERATIONS = 100


# ---------------------------------------------------------------------------------------------- calibration


def calibration_from_hamlyn_folder(folder: str | Path, image_size: tuple[int, int]) -> StereoCalibration:
    """Calibration from a Hamlyn-style folder (``HAMLYN_FILES``; the l2r transform in millimetres)."""
    folder = Path(folder)
    arrays = {}
    for key, name in HAMLYN_FILES.items():
        path = folder / name
        if not path.is_file():
            raise ValueError(f"missing {name} (a calibration folder holds {', '.join(HAMLYN_FILES.values())})")
        try:
            arrays[key] = np.loadtxt(path, ndmin=1)
        except ValueError as exc:
            raise ValueError(f"{name}: not a table of numbers ({exc})") from None
    l2r_name = HAMLYN_FILES["l2r_mm"]
    try:
        l2r = np.asarray(arrays["l2r_mm"], dtype=np.float64).reshape(4, 4)
    except ValueError:
        raise ValueError(f"{l2r_name} must have 16 numbers (4x4), got {arrays['l2r_mm'].size}") from None
    keys = (*(HAMLYN_FILES[k] for k in ("K_left", "D_left", "K_right", "D_right")), l2r_name, l2r_name)
    return StereoCalibration.from_matrices(arrays["K_left"], arrays["D_left"], arrays["K_right"], arrays["D_right"],
                                           l2r[:3, :3], l2r[:3, 3] / 1000.0, *image_size, keys=keys,
                                           source=str(folder))


def read_stereo_calibration(path: str | Path, image_size: tuple[int, int] | None = None) -> StereoCalibration:
    """Read a stereo calibration: an OpenCV FileStorage file (``.yaml``/``.yml``/``.xml``: ``K1 D1 K2 D2 R T``
    and ``image_width``, ``image_height``), a calibration JSON
    (:meth:`~rgbd2scene.geometry.stereo.StereoCalibration.from_dict`) or a Hamlyn-style folder. A folder, and a
    FileStorage file without the image size, take it from ``image_size`` (w, h).

    Raises ``ValueError`` naming the key of a malformed calibration and ``OSError`` when it cannot be read.
    """
    path = Path(path)
    if path.is_dir():
        if image_size is None:
            raise ValueError("a calibration folder does not give the image size")
        return calibration_from_hamlyn_folder(path, image_size)
    if path.suffix.lower() in OPENCV_SUFFIXES:
        nodes = read_opencv_calibration(path)
        if nodes is None:
            raise ValueError("not an OpenCV FileStorage file")
        missing = [key for key in OPENCV_CALIB_KEYS if nodes.get(key) is None]
        if missing:
            raise ValueError(f"missing key(s) {', '.join(missing)} (a calibration holds {' '.join(OPENCV_CALIB_KEYS)} "
                             f"and {', '.join(OPENCV_SIZE_KEYS)})")
        if all(key in nodes for key in OPENCV_SIZE_KEYS):
            image_size = tuple(int(nodes[key]) for key in OPENCV_SIZE_KEYS)
        if image_size is None:
            raise ValueError(f"no image size ({' and '.join(OPENCV_SIZE_KEYS)})")
        return StereoCalibration.from_matrices(*(nodes[key] for key in OPENCV_CALIB_KEYS), *image_size,
                                               keys=OPENCV_CALIB_KEYS, source=str(path))
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"not valid JSON ({exc})") from None
    return StereoCalibration.from_dict(data, source=str(path))




def read_opencv_calibration(path: str | Path) -> dict | None:
    """The nodes of an OpenCV FileStorage stereo calibration (``.yaml``/``.yml``/``.xml``): each of
    ``OPENCV_CALIB_KEYS`` the file holds as ``node.mat()`` and each of ``OPENCV_SIZE_KEYS`` as a number; the
    keys the file lacks are left out. None when OpenCV does not open the file; ``ValueError`` for an empty or
    malformed file and for a matrix key that holds no matrix. The callers check the keys and word their own
    errors."""
    if Path(path).stat().st_size == 0:
        raise ValueError("an empty file, not an OpenCV FileStorage calibration")
    try:
        # A malformed file: cv2.error, or (OpenCV 4.11's constructor) a SystemError caused by one.
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        raise ValueError(f"not an OpenCV FileStorage file ({_opencv_reason(exc)})") from None
    try:
        if not fs.isOpened():
            return None
        if not fs.root().isMap():
            raise ValueError("not an OpenCV FileStorage calibration (its top level is not a map of keys)")
        nodes = {}
        for key in (*OPENCV_CALIB_KEYS, *OPENCV_SIZE_KEYS):
            node = fs.getNode(key)
            if node.empty():
                continue
            if key in OPENCV_SIZE_KEYS:
                nodes[key] = node.real()
            elif node.isMap():
                nodes[key] = node.mat()
            else:
                raise ValueError(f"{key} is not a matrix (an OpenCV opencv-matrix node)")
        return nodes
    finally:
        fs.release()


def _opencv_reason(exc: BaseException) -> str:
    """What the OpenCV error behind ``exc`` says (its cause where OpenCV wrapped it), without its source line."""
    text = str(exc.__cause__ or exc.__context__ or exc).strip()
    found = re.search(r"error: \([^)]*\) (.*?)(?: in function .*)?$", text, flags=re.MULTILINE)
    return f"OpenCV: {found.group(1)}" if found else text.splitlines()[-1] if text else type(exc).__name__


# ---------------------------------------------------------------------------------------------- rectification


def rectify(calib: StereoCalibration, alpha: float = 1.0, keep_resolution: bool = True) -> Rectification:
    """Rectifying rotations and projections of a calibrated pair (principal points made equal):
    :func:`~rgbd2scene.geometry.rectification.stereo_rectification` of ``calib``.

    ``alpha`` as in ``cv2.stereoRectify`` (1: keep every source pixel, 0: only pixels valid in both).
    ``keep_resolution`` enlarges the rectified image so that its focal length is not below the one of
    ``alpha=-1`` (no scaling), see the module docstring.
    """
    return stereo_rectification(calib.K_left, calib.D_left, calib.K_right, calib.D_right, calib.size, calib.R,
                                calib.T, alpha=alpha, keep_resolution=keep_resolution)


@dataclass
class RectifiedPair:
    """Rectified RGB images and their masks of pixels that hold image data (the rest are empty margins)."""

    left: np.ndarray
    right: np.ndarray
    left_mask: np.ndarray
    right_mask: np.ndarray


def rectify_pair(calib: StereoCalibration, rect: Rectification, left: np.ndarray, right: np.ndarray) -> RectifiedPair:
    """Undistort and rectify both images (bilinear); a pixel holds image data when its bilinear footprint
    lies wholly inside the source image."""
    out = []
    for eye, image, K, D in (("left", left, calib.K_left, calib.D_left),
                             ("right", right, calib.K_right, calib.D_right)):
        mx, my = rect.maps(eye, K, D)
        mask = (mx >= 0) & (my >= 0) & (mx <= calib.width - 1) & (my <= calib.height - 1)
        out.append((cv2.remap(image, mx, my, cv2.INTER_LINEAR), mask))
    return RectifiedPair(out[0][0], out[1][0], out[0][1], out[1][1])


# ---------------------------------------------------------------------------------------------- matching


@dataclass
class StereoOptions:
    """Stereo matching and confidence settings (recorded in scene.json).

    min_depth, max_depth : metres, the expected depth range; it sets the disparities searched.
    matcher : "auto" (ELAS when ``import elas`` works, else SGBM), "sgbm" or "elas".
    block_size : SGBM window (odd px); None: about width / 100, at least 3.
    max_lr_difference : px, left-right consistency tolerance.
    min_texture_std : grey levels, least standard deviation in the block window.
    saturation : grey level from which a pixel counts as a saturated highlight (0 disables).
    speckle_fraction : disparity regions smaller than this fraction of the image are dropped.
    speckle_range : px, neighbours within this disparity difference belong to one region.
    alpha, keep_resolution : rectification, see :func:`rectify`.
    """

    min_depth: float = 0.02
    max_depth: float = 0.5
    matcher: str = "auto"
    block_size: int | None = None
    max_lr_difference: float = 1.0
    min_texture_std: float = 1.0
    saturation: int = 250
    speckle_fraction: float = 0.002
    speckle_range: float = 2.0
    alpha: float = 1.0
    keep_resolution: bool = True

    def to_dict(self) -> dict:
        return dict(self.__dict__)

    def check(self) -> None:
        if self.matcher not in MATCHERS:
            raise ValueError(f"unknown stereo matcher {self.matcher!r}; choose one of {', '.join(MATCHERS)}")
        if not 0 < self.min_depth < self.max_depth:
            raise ValueError(f"the depth range must satisfy 0 < min < max, got {self.min_depth}..{self.max_depth} m")
        if self.block_size is not None and (self.block_size < 1 or self.block_size % 2 == 0):
            raise ValueError(f"the block size must be odd and positive, got {self.block_size}")


def elas_available() -> bool:
    try:
        import elas
    except ImportError:
        return False
    return hasattr(elas, "Elas")


def disparity_range(f: float, baseline: float, min_depth: float, max_depth: float) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering depths min_depth..max_depth; num is a multiple of 16 (SGBM)."""
    d_min = int(math.floor(f * baseline / max_depth))
    d_max = int(math.ceil(f * baseline / min_depth))
    return d_min, max(16, 16 * math.ceil((d_max - d_min) / 16))


def _to_float_disparity(raw: np.ndarray, d_min: float) -> np.ndarray:
    """OpenCV/ELAS disparities (px) as float32 with NaN where the matcher found none."""
    d = raw.astype(np.float32)
    d[~(d >= max(d_min, 1e-3))] = np.nan
    return d


def match_sgbm(left: np.ndarray, right: np.ndarray, d_min: int, n_disp: int,
               block: int) -> tuple[np.ndarray, np.ndarray]:
    """Left and right disparity maps (px, NaN = none) of rectified grey images by semi-global matching.

    The images are padded by the disparity range so that the columns SGBM leaves empty (the first
    ``d_min + n_disp`` of the left view) fall in the padding; the right view's disparities come from
    ``cv2.ximgproc.createRightMatcher``. P1, P2 = 8 and 32 block^2 (OpenCV's recommendation); the full
    8-path mode (``MODE_HH``): on the Hamlyn phantom the faster 3-way mode leaves blocky terraces (median
    |Laplacian| of depth 0.19 mm against 0.17 mm, ELAS 0.11 mm) for 0.3 s instead of 0.08 s.
    """
    pad = d_min + n_disp
    sgbm = cv2.StereoSGBM_create(minDisparity=d_min, numDisparities=n_disp, blockSize=block, P1=8 * block * block,
                                 P2=32 * block * block, uniquenessRatio=10, mode=cv2.STEREO_SGBM_MODE_HH)
    w = left.shape[1]
    padded = [cv2.copyMakeBorder(img, 0, 0, pad, 0, cv2.BORDER_REPLICATE) for img in (left, right)]
    disp_left = sgbm.compute(*padded)[:, pad:] / 16.0
    padded = [cv2.copyMakeBorder(img, 0, 0, 0, pad, cv2.BORDER_REPLICATE) for img in (right, left)]
    disp_right = -cv2.ximgproc.createRightMatcher(sgbm).compute(*padded)[:, :w] / 16.0
    return _to_float_disparity(disp_left, d_min), _to_float_disparity(disp_right, d_min)


def match_elas(left: np.ndarray, right: np.ndarray, d_min: int, n_disp: int) -> tuple[np.ndarray, np.ndarray]:
    """Left and right disparity maps (px, NaN = none) by ELAS (Geiger et al. 2010), robotics preset,
    both views post-processed (our own left-right check follows)."""
    from elas import Elas

    elas = Elas()
    elas.disp_min, elas.disp_max = int(d_min), int(d_min + n_disp)
    elas.postprocess_only_left = False
    disp_left, disp_right = elas.process(np.ascontiguousarray(left), np.ascontiguousarray(right))
    return _to_float_disparity(disp_left, d_min), _to_float_disparity(disp_right, d_min)


def left_right_consistent(disp_left: np.ndarray, disp_right: np.ndarray, max_difference: float = 1.0) -> np.ndarray:
    """Left pixels whose match (u - d, v) in the right view has a disparity within ``max_difference`` px.

    Disparities follow CONVENTIONS section 2 (positive, NaN = none); False where either is missing.
    """
    h, w = disp_left.shape
    u = np.arange(w, dtype=np.float64)[None, :]
    with np.errstate(invalid="ignore"):
        ur = np.rint(u - disp_left)
        inside = np.isfinite(ur) & (ur >= 0) & (ur <= w - 1)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    other = np.full((h, w), np.nan, dtype=np.float32)
    other[inside] = disp_right[rows[inside], ur[inside].astype(np.int64)]
    with np.errstate(invalid="ignore"):
        return inside & (np.abs(other - disp_left) <= max_difference)


def textured(grey: np.ndarray, window: int, min_std: float, saturation: int = 0) -> np.ndarray:
    """Pixels whose ``window`` x ``window`` neighbourhood has a grey-level standard deviation of at least
    ``min_std`` and (with ``saturation`` > 0) holds no pixel at or above ``saturation``."""
    g = grey.astype(np.float32)
    mean = cv2.boxFilter(g, -1, (window, window))
    mean_sq = cv2.boxFilter(g * g, -1, (window, window))
    ok = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0)) >= min_std
    if saturation > 0:
        saturated = (grey >= saturation).astype(np.uint8)
        ok &= cv2.dilate(saturated, np.ones((window, window), np.uint8)) == 0
    return ok


def speckle_free(disparity: np.ndarray, max_size: int, max_difference: float) -> np.ndarray:
    """Pixels of connected disparity regions (neighbours within ``max_difference`` px) larger than
    ``max_size`` pixels (``cv2.filterSpeckles``); False where the disparity is NaN."""
    valid = np.isfinite(disparity)
    fixed = np.where(valid, np.rint(disparity * 16.0), -16).astype(np.int16)
    cv2.filterSpeckles(fixed, -16, int(max_size), int(round(max_difference * 16)))
    return valid & (fixed >= 0)


def percentiles(values: np.ndarray, qs: tuple[float, ...]) -> dict[str, float]:
    """``{"q": value}`` percentiles of ``values`` (empty when there are none)."""
    if values.size == 0:
        return {}
    return {f"{q:g}": float(v) for q, v in zip(qs, np.percentile(values, qs), strict=True)}


@dataclass
class StereoDepth:
    """Confident depth (float32 metres, NaN elsewhere) in the rectified left camera, its disparity and stats."""

    depth: np.ndarray
    disparity: np.ndarray
    stats: dict


def stereo_depth(pair: RectifiedPair, f: float, baseline: float, options: StereoOptions | None = None) -> StereoDepth:
    """Depth of a rectified pair where the match is confident (see the module docstring).

    A match counts only when the matching windows lie inside the image data of both views (the edges
    of the empty margins would match each other); fractions in the stats are of the left image data.
    """
    options = options or StereoOptions()
    options.check()
    t0 = time.perf_counter()
    grey_left = cv2.cvtColor(pair.left, cv2.COLOR_RGB2GRAY)
    grey_right = cv2.cvtColor(pair.right, cv2.COLOR_RGB2GRAY)
    h, w = grey_left.shape
    d_min, n_disp = disparity_range(f, baseline, options.min_depth, options.max_depth)
    block = options.block_size or max(3, 2 * round(w / 200) + 1)
    matcher = options.matcher
    if matcher == "auto":
        matcher = "elas" if elas_available() else "sgbm"
    if matcher == "elas":
        if not elas_available():
            raise ValueError("the ELAS matcher needs the pyelas package (import elas failed)")
        disp_left, disp_right = match_elas(grey_left, grey_right, d_min, n_disp)
    else:
        disp_left, disp_right = match_sgbm(grey_left, grey_right, d_min, n_disp, block)
    t_match = time.perf_counter() - t0

    window = np.ones((block, block), np.uint8)
    inside_left, inside_right = (cv2.erode(m.astype(np.uint8), window, borderValue=0) > 0
                                 for m in (pair.left_mask, pair.right_mask))
    image_mask = pair.left_mask
    matched = np.isfinite(disp_left) & inside_left
    consistent = left_right_consistent(np.where(inside_left, disp_left, np.nan),
                                       np.where(inside_right, disp_right, np.nan), options.max_lr_difference)
    texture = textured(grey_left, block, options.min_texture_std, options.saturation)
    speckle_size = max(1, round(options.speckle_fraction * h * w))
    # An opening drops confident structures thinner than 3 px (e.g. video border lines matched as edges).
    thick = cv2.morphologyEx((consistent & texture).astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    kept = speckle_free(np.where(thick, disp_left, np.nan), speckle_size, options.speckle_range)
    disparity = np.where(kept, disp_left, np.nan).astype(np.float32)
    depth = depth_from_disparity(disparity, f, baseline)
    n_image = max(int(image_mask.sum()), 1)
    finite = depth[np.isfinite(depth)]
    stats = {
        "matcher": matcher, "min_disparity": d_min, "num_disparities": n_disp, "block_size": block,
        "speckle_max_size_px": speckle_size, "focal_px": float(f), "baseline_m": float(baseline),
        "image_fraction": float(image_mask.mean()),
        "matched_fraction": float(matched.sum() / n_image),
        "left_right_consistent_fraction": float(consistent.sum() / n_image),
        "textured_fraction": float((texture & image_mask).sum() / n_image),
        "coverage": float(kept.sum() / n_image),
        "depth_percentiles_m": percentiles(finite, (1, 5, 50, 95, 99)),
        "match_s": round(t_match, 4), "seconds": round(time.perf_counter() - t0, 4),
    }
    return StereoDepth(depth, disparity, stats)


# ---------------------------------------------------------------------------------------------- capture


def load_stereo_capture(left_path: str | Path, right_path: str | Path, calib_path: str | Path,
                        options: StereoOptions | None = None) -> Capture:
    """Read a stereo frame and its calibration and return the rectified RGB-D :class:`Capture`.

    Every problem is a one-line ``UserError`` naming the file (images, calibration, their sizes).
    """
    options = options or StereoOptions()
    left, right = read_rgb(left_path), read_rgb(right_path)
    if left.shape != right.shape:
        raise UserError(f"{right_path}: the right image is {right.shape[1]}x{right.shape[0]} but the left image "
                        f"{left_path} is {left.shape[1]}x{left.shape[0]}")
    size = (left.shape[1], left.shape[0])
    try:
        calib = read_stereo_calibration(calib_path, image_size=size)
    except (OSError, ValueError) as exc:
        raise UserError(f"{calib_path}: bad stereo calibration: {exc}") from None
    if calib.size != size:
        raise UserError(f"{left_path}: the images are {size[0]}x{size[1]} but the calibration {calib_path} is for "
                        f"{calib.width}x{calib.height}")
    t0 = time.perf_counter()
    rect = rectify(calib, alpha=options.alpha, keep_resolution=options.keep_resolution)
    pair = rectify_pair(calib, rect, left, right)
    t_rectify = time.perf_counter() - t0
    try:
        result = stereo_depth(pair, rect.K[0, 0], rect.baseline, options)
    except ValueError as exc:
        raise UserError(f"stereo: {exc}") from None
    if not np.isfinite(result.depth).any():
        raise UserError(f"{left_path}: no confident stereo depth (check the calibration {calib_path}, the image "
                        f"order and the depth range {options.min_depth}-{options.max_depth} m)")
    intrinsics = Intrinsics.from_K(rect.K, rect.width, rect.height)
    info = {"stereo": {"left": str(left_path), "right": str(right_path), "calibration": str(calib_path),
                       "calibration_values": calib.to_dict(), "rectification": rect.to_dict(),
                       "options": options.to_dict(), "stats": {**result.stats, "rectify_s": round(t_rectify, 4)}}}
    return Capture(pair.left, result.depth, intrinsics, rgb_path=str(left_path),
                   depth_path=f"{left_path}, {right_path}", depth_format="stereo", depth_scale=None, info=info,
                   T_world_capture=rect.T_left_rectified, image_mask=pair.left_mask)
