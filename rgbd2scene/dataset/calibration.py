"""``DATASET/calibration.yaml`` (CONVENTIONS 1.2, section 2): the rig of the images as written, for OpenCV.

``cv2.FileStorage`` reads it: ``K1 D1 K2 D2 R T`` (metres; ``X_right = R X_left + T``), ``image_width``,
``image_height``, and for a rectified dataset ``R1 R2 P1 P2 Q`` as well (its own rectification: identities
and the shared K).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgbd2scene.files.atomic import atomic_path
from rgbd2scene.scene.rig import StereoRig, rectification

CALIBRATION_YAML = "calibration.yaml"


def write_calibration(root: str | Path, rig: StereoRig) -> Path:
    """Write ``root/calibration.yaml`` of ``rig`` (the rig as rendered, at the dataset's image size) atomically."""
    import cv2

    path = Path(root) / CALIBRATION_YAML
    with atomic_path(path) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        try:
            fs.write("image_width", int(rig.left.width))
            fs.write("image_height", int(rig.left.height))
            fs.write("K1", rig.left.K)
            fs.write("D1", rig.left.distortion.reshape(1, -1))
            fs.write("K2", rig.right.K)
            fs.write("D2", rig.right.distortion.reshape(1, -1))
            fs.write("R", np.asarray(rig.R, dtype=np.float64))
            fs.write("T", np.asarray(rig.T, dtype=np.float64).reshape(3, 1))
            fs.write("rectified", int(rig.rectified))
            if rig.rectified:
                rect = rectification(rig)
                for name in ("R1", "R2", "P1", "P2", "Q"):
                    fs.write(name, np.asarray(getattr(rect, name), dtype=np.float64))
        finally:
            fs.release()
    return path
