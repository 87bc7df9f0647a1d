"""Where stereo methods match, and how their disparities are scored against the dataset's ground truth.

A rectified dataset is matched as written: its disparity ``d`` is scored as depth ``fx·B/d``.

A raw dataset (CONVENTIONS 1.2: the scope's distortion and unequal eyes, every map in the distorted pixel grid)
cannot be matched as written: stereo methods search along image rows, which a raw pair's epipolar lines are
not. It is rectified first, as ``render --rectify`` and ``calibration.yaml`` define the rectified pair
(``cv2.stereoRectify``, alpha 0: :meth:`~rgbd2scene.geometry.stereo.StereoCalibration.rectification`), and each
method's disparity, found in that grid, is scored at the raw left pixels, where the ground truth is exact: a raw
pixel's own ray (:meth:`~rgbd2scene.geometry.camera.Camera.rays`) lands at a point of the rectified image, where
the prediction is read (nearest pixel: no blend across depth edges; at most half a rectified pixel away); the
depth it gives along the rectified camera's axis, ``f_r·B/d``, is turned into the planar depth of the raw camera
along the same ray. The ground truth is never resampled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.dataset.reader import Dataset


@dataclass(frozen=True)
class MatchingGrid:
    """The image grid stereo methods match in (``focal`` px, ``baseline`` m), and its way back to the dataset's.

    ``rectify``: per eye the ``cv2.remap`` maps from the raw image to the rectified one, None for a rectified
    dataset (identity); ``lookup``: per raw left pixel its place in the rectified left image (map_x, map_y),
    and ``gain``: the factor turning a rectified disparity read there into the disparity ``fx·B/z`` of the
    raw pixel's planar depth z (NaN where the pixel has no ray).
    """

    focal: float
    baseline: float
    scoring_focal: float
    rectify: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    lookup: tuple[np.ndarray, np.ndarray] | None = None
    gain: np.ndarray | None = None

    @property
    def raw(self) -> bool:
        return self.rectify is not None

    @classmethod
    def of(cls, dataset: Dataset) -> MatchingGrid:
        """The dataset's own grid when it is rectified, else the rectified grid of its rig (see the module)."""
        if dataset.rectified:
            return cls(dataset.fx, dataset.baseline, dataset.fx)
        rig = dataset.rig
        rect = rig.calibration.rectification()
        rectify = {eye: rect.maps(eye, rig.camera(eye).K, rig.camera(eye).distortion) for eye in ("left", "right")}
        P1 = np.asarray(rect.P1, dtype=np.float64)
        f = float(P1[0, 0])
        rays = rig.left.rays() @ np.asarray(rect.R1, dtype=np.float64).T  # raw left rays, rectified frame
        with np.errstate(invalid="ignore", divide="ignore"):
            ahead = rays[..., 2] > 0
            u = np.where(ahead, P1[0, 0] * rays[..., 0] / rays[..., 2] + P1[0, 2], -1.0)
            v = np.where(ahead, P1[1, 1] * rays[..., 1] / rays[..., 2] + P1[1, 2], -1.0)
            # along a raw ray of unit z, the rectified depth is z_raw * rays_z: z_raw = f B / (d rays_z), and the
            # raw pixel's disparity fx B / z_raw = d * fx rays_z / f
            gain = np.where(ahead, dataset.fx * rays[..., 2] / f, np.nan)
        return cls(f, rig.baseline, dataset.fx, rectify,
                   (u.astype(np.float32), v.astype(np.float32)), gain)

    def pair(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The images methods match: the pair itself, or rectified (bilinear, black outside the raw image)."""
        if self.rectify is None:
            return left, right
        import cv2

        return tuple(cv2.remap(image, *self.rectify[eye], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0) for eye, image in (("left", left), ("right", right)))

    def to_scoring(self, disparity: np.ndarray) -> np.ndarray:
        """A disparity found in this grid as the disparity ``scoring_focal·B/z`` of each dataset pixel's depth
        z (float32; NaN where the method gave none, or the pixel's ray leaves the rectified image)."""
        d = np.asarray(disparity, dtype=np.float32)
        if self.rectify is None:
            return d
        import cv2

        read = cv2.remap(d, *self.lookup, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        return (read * self.gain).astype(np.float32)
