"""The dataset folder of CONVENTIONS.md section 4 (numpy only, no ``bpy``).

```
DATASET/dataset.json
DATASET/left/rgb/000000.png     8-bit sRGB
DATASET/left/gt/000000.npz      the keys of section 3
DATASET/right/rgb/000000.png
DATASET/right/gt/000000.npz
```

Every file is written to a temporary name in its own folder and renamed into place, so a frame whose
four files exist is complete; :func:`frame_done` is what resuming relies on.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import secrets
import shutil
import socket
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

from rgbd2scene.errors import UserError
from rgbd2scene.files.atomic import atomic_path, read_json_object, write_json
from rgbd2scene.files.images import read_image, write_image

EYES = ("left", "right")
DATASET_JSON = "dataset.json"
#: Scratch folder of a running render (Blender's own outputs before they are renamed into place).
WORK_DIR = ".work"
#: Deformed vertex positions per frame (CONVENTIONS §4).
GEOMETRY_DIR = "geometry"
#: Keys dataset.json must have (CONVENTIONS §4 plus this project's render record).
REQUIRED_KEYS = ("width", "height", "frames", "fps", "baseline", "K", "objects", "scene", "software", "seed",
                 "conventions_version", "render")
FORMAT = "rgbd2scene-dataset"
#: zlib level of the npz files' integer and boolean arrays (ids, occlusion flags: they compress to almost
#: nothing). Float arrays (depth, normals, flow, vertex positions...) are stored: their low mantissa bits are
#: noise to zlib (depth and disparity shrink to 0.83, flow to 0.86-0.90, normals to 0.91 of their size) and
#: deflating them took most of the ground truth's time without Blender (0.4 s of 0.75 s per 512x256 eye,
#: ``render --gt-only``, loaded machine).
NPZ_COMPRESSLEVEL = 1
#: zlib level of the RGB PNGs: level 1 encodes a 512x256 frame in 7.5 ms instead of 12.6 ms (level 3, OpenCV's
#: default) for 2 % more bytes (214 kB instead of 210 kB); the pixels are the same.
RGB_PNG_COMPRESSION = 1
#: ZipInfo's compression-level attribute (``_compresslevel`` up to Python 3.12, ``compress_level`` after)
_LEVEL_SLOT = "compress_level" if "compress_level" in zipfile.ZipInfo.__slots__ else "_compresslevel"


class FramePaths(NamedTuple):
    rgb: Path
    gt: Path


def frame_name(index: int) -> str:
    """Zero-based, six digits."""
    if index < 0:
        raise ValueError(f"frame index must be >= 0, got {index}")
    return f"{int(index):06d}"


def frame_paths(root: str | Path, eye: str, index: int) -> FramePaths:
    """Paths of one eye's RGB image and ground-truth npz of frame ``index``."""
    if eye not in EYES:
        raise ValueError(f"eye must be one of {EYES}, got {eye!r}")
    root = Path(root)
    name = frame_name(index)
    return FramePaths(root / eye / "rgb" / f"{name}.png", root / eye / "gt" / f"{name}.npz")


def rgb_done(root: str | Path, index: int) -> bool:
    return all(frame_paths(root, eye, index).rgb.is_file() for eye in EYES)


def geometry_path(root: str | Path, index: int) -> Path:
    """``DATASET/geometry/NNNNNN.npz``: the deformed vertices of frame ``index`` (deforming scenes only)."""
    return Path(root) / GEOMETRY_DIR / f"{frame_name(index)}.npz"


def gt_done(root: str | Path, index: int, geometry: bool = False) -> bool:
    """Both eyes' npz present and, with ``geometry`` (a deforming scene), the frame's geometry file."""
    return (all(frame_paths(root, eye, index).gt.is_file() for eye in EYES)
            and (not geometry or geometry_path(root, index).is_file()))


def frame_done(root: str | Path, index: int, gt: bool = True, geometry: bool = False) -> bool:
    """Both eyes' RGB PNG present and, with ``gt``, the ground truth too (see :func:`gt_done`)."""
    return rgb_done(root, index) and (not gt or gt_done(root, index, geometry))


def write_rgb(path: str | Path, rgb_uint8: np.ndarray) -> None:
    """8-bit RGB (H, W, 3) -> PNG, atomically (OpenCV writes to a temporary name, then rename)."""
    rgb = np.asarray(rgb_uint8)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be uint8 (H, W, 3), got {rgb.dtype} {rgb.shape}")
    write_image(path, rgb, compression=RGB_PNG_COMPRESSION)


def write_gt(path: str | Path, gt: dict, compresslevel: int = NPZ_COMPRESSLEVEL, scratch: Path | None = None) -> None:
    """Ground-truth dict -> compressed npz (a standard one: ``np.load`` reads it), atomically.

    Deflate level ``compresslevel`` for integer and boolean arrays, float arrays stored
    (:data:`NPZ_COMPRESSLEVEL`); fixed entry dates, so the same arrays give the same bytes.
    """
    with atomic_path(path, suffix=".npz", tmp_dir=scratch) as tmp, zipfile.ZipFile(
            tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=compresslevel) as zf:
        for key, value in gt.items():
            value = np.asanyarray(value)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            stored = np.issubdtype(value.dtype, np.floating)
            info.compress_type = zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            setattr(info, _LEVEL_SLOT, compresslevel)
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, value, allow_pickle=False)


def write_frame(root: str | Path, eye: str, index: int, rgb_uint8: np.ndarray | None,
                gt_dict: dict | None) -> FramePaths:
    """Write one eye of one frame (either part may be None: not written)."""
    paths = frame_paths(root, eye, index)
    if gt_dict is not None:
        write_gt(paths.gt, gt_dict)
    if rgb_uint8 is not None:
        write_rgb(paths.rgb, rgb_uint8)
    return paths


def read_frame(root: str | Path, eye: str, index: int, rgb: bool = True) -> tuple[np.ndarray | None, dict]:
    """(RGB uint8 (H, W, 3) or None, ground-truth dict) of one eye and frame."""
    paths = frame_paths(root, eye, index)
    image = None
    if rgb:
        image = read_image(paths.rgb)
        if image is None:
            raise UserError(f"{paths.rgb}: missing or unreadable image")
    gt: dict = {}
    if paths.gt.is_file():
        with np.load(paths.gt) as data:
            gt = {k: data[k] for k in data.files}
    return image, gt


def write_dataset_json(root: str | Path, info: dict) -> Path:
    """Write DATASET/dataset.json atomically; ``info`` must hold :data:`REQUIRED_KEYS`."""
    missing = [k for k in REQUIRED_KEYS if k not in info]
    if missing:
        raise ValueError(f"dataset.json info lacks {', '.join(missing)}")
    out = {"format": FORMAT}
    out.update(info)
    path = Path(root) / DATASET_JSON
    write_json(path, out)
    return path


def read_dataset_json(root: str | Path) -> dict:
    path = Path(root) / DATASET_JSON
    if not path.is_file():
        raise UserError(f"{path}: not found (not a dataset folder made by 'rgbd2scene render')")
    return read_json_object(path, "dataset.json")


@contextlib.contextmanager
def scratch_dir(root: str | Path) -> Iterator[Path]:
    """A private scratch folder ``DATASET/.work/<host>-<pid>-<random>/`` for one worker run.

    Every file the run writes is made there and renamed into place when complete, and the run holds an
    exclusive lock on ``lock`` inside it while alive, so :func:`sweep_dead_runs` can tell a dead run's
    leftovers (lock free: removed) from a live run's work (lock held: kept), whatever their age.
    """
    work = Path(root) / WORK_DIR
    work.mkdir(parents=True, exist_ok=True)
    folder = work / f"{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(3)}"
    folder.mkdir()
    fd = os.open(folder / "lock", os.O_CREAT | os.O_RDWR, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        os.close(fd)
        with contextlib.suppress(OSError):
            work.rmdir()  # only when no other run's folder is left in it


def lock_held(path: str | Path) -> bool:
    """Whether a live process holds an exclusive ``flock`` on the lock file ``path`` (False when it is absent)."""
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # closing releases a lock we got
    return False


def sweep_dead_runs(root: str | Path) -> int:
    """Remove what killed runs left in a dataset folder: scratch folders whose lock is free, and atomic
    writers' ``.NAME.*`` temporaries beside the frames and dataset.json (live runs make theirs in their
    scratch folder, so these can only be a dead run's). Returns the number of files removed."""
    root = Path(root)
    count = 0
    strays = [p for eye in EYES for kind in ("rgb", "gt") for p in (root / eye / kind).glob(".*")]
    strays += list((root / GEOMETRY_DIR).glob(".*"))
    strays += list(root.glob(f".{Path(DATASET_JSON).stem}.*"))
    for p in strays:
        with contextlib.suppress(FileNotFoundError):
            if p.is_file():
                p.unlink()
                count += 1
    work = root / WORK_DIR
    if work.is_dir():
        for entry in work.iterdir():
            if entry.is_dir() and not lock_held(entry / "lock"):
                count += sum(1 for q in entry.rglob("*") if q.is_file())
                shutil.rmtree(entry, ignore_errors=True)
            elif entry.is_file():  # a file of the older flat layout
                entry.unlink(missing_ok=True)
                count += 1
        with contextlib.suppress(OSError):
            work.rmdir()  # only when empty
    return count


#: Per-frame sensor records (auto exposure): ``DATASET/sensor/NNNNNN.json``.
SENSOR_DIR = "sensor"
#: The noise-free images beside the noisy ones (``--clean``): ``DATASET/{eye}/rgb_clean/NNNNNN.png``.
CLEAN_DIR = "rgb_clean"


def sensor_path(root: str | Path, index: int) -> Path:
    """``DATASET/sensor/NNNNNN.json``: how frame ``index`` was exposed (written before its PNGs)."""
    return Path(root) / SENSOR_DIR / f"{frame_name(index)}.json"


def clean_rgb_path(root: str | Path, eye: str, index: int) -> Path:
    """``DATASET/{eye}/rgb_clean/NNNNNN.png``: the image without noise and compression (written before the
    noisy one, so a frame whose ``rgb`` PNGs exist has it)."""
    return frame_paths(root, eye, index).rgb.parent.parent / CLEAN_DIR / f"{frame_name(index)}.png"


def write_sensor_record(root: str | Path, index: int, record: dict) -> None:
    write_json(sensor_path(root, index), record)


def read_sensor_record(root: str | Path, index: int) -> dict | None:
    """The sensor record of frame ``index``, or None when it is missing."""
    path = sensor_path(root, index)
    return read_json_object(path, "sensor record") if path.is_file() else None
