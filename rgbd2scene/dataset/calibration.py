"""``DATASET/calibration.yaml`` (CONVENTIONS 1.2, section 2): the rig of the images as written, for OpenCV.

``cv2.FileStorage`` reads it: ``K1 D1 K2 D2 R T`` (metres; ``X_right = R X_left + T``), ``image_width``,
``image_height``, and for a rectified dataset ``R1 R2 P1 P2 Q`` as well (its own rectification: identities
and the shared K).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgbd2scene.files.atomic import atomic_path
from rgbd2scene.geometry.stereo import StereoCalibration

CALIBRATION_YAML = "calibration.yaml"


def write_calibration(root: str | Path, calibration: StereoCalibration) -> Path:
    """Write ``root/calibration.yaml`` of ``calibration`` (the rig's as rendered, at the dataset's image size)
    atomically."""
    import cv2

    path = Path(root) / CALIBRATION_YAML
    with atomic_path(path) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        try:
            fs.write("image_width", int(calibration.width))
            fs.write("image_height", int(calibration.height))
            fs.write("K1", calibration.K_left)
            fs.write("D1", calibration.D_left.reshape(1, -1))
            fs.write("K2", calibration.K_right)
            fs.write("D2", calibration.D_right.reshape(1, -1))
            fs.write("R", np.asarray(calibration.R, dtype=np.float64))
            fs.write("T", np.asarray(calibration.T, dtype=np.float64).reshape(3, 1))
            fs.write("rectified", int(calibration.rectified))
            if calibration.rectified:
                rect = calibration.rectification()
                for name in ("R1", "R2", "P1", "P2", "Q"):
                    fs.write(name, np.asarray(getattr(rect, name), dtype=np.float64))
        finally:
            fs.release()
    return path
