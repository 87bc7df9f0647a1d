"""Float image files of other datasets' formats, written atomically through OpenCV's own codecs.

- PFM (``Pf``, one channel float32, little-endian, rows bottom to top): OpenCV's PFM codec.
- Middlebury ``.flo`` (``PIEH`` tag, width, height, then (u, v) float32 pairs row by row): ``cv2.writeOpticalFlow``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgbd2scene.files.atomic import atomic_path


def write_pfm(path: str | Path, image: np.ndarray) -> Path:
    """One-channel float32 (H, W) image -> PFM (NaN and inf are stored as they are)."""
    import cv2

    a = np.ascontiguousarray(image, dtype=np.float32)
    if a.ndim != 2:
        raise ValueError(f"PFM image must be (H, W), got {a.shape}")
    path = Path(path)
    with atomic_path(path, suffix=".pfm") as tmp:
        if not cv2.imwrite(str(tmp), a):
            raise OSError(f"{path}: OpenCV could not write the PFM file")
    return path


def read_pfm(path: str | Path) -> np.ndarray | None:
    """float32 (H, W) of a one-channel PFM file, or None when it is missing or unreadable."""
    import cv2

    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return None if a is None else np.asarray(a, np.float32)


def write_flo(path: str | Path, flow: np.ndarray) -> Path:
    """Flow (H, W, 2) float32 -> Middlebury ``.flo``."""
    import cv2

    f = np.ascontiguousarray(flow, dtype=np.float32)
    if f.ndim != 3 or f.shape[2] != 2:
        raise ValueError(f"flow must be (H, W, 2), got {f.shape}")
    path = Path(path)
    with atomic_path(path, suffix=".flo") as tmp:
        if not cv2.writeOpticalFlow(str(tmp), f):
            raise OSError(f"{path}: OpenCV could not write the .flo file")
    return path
