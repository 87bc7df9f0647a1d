"""``disparity``: the disparity map equals fx*B/z of the depth map (CONVENTIONS.md section 2)."""

from __future__ import annotations

import numpy as np

from rgbd2scene.conventions import disparity_from_depth
from rgbd2scene.dataset.layout import EYES
from rgbd2scene.verify.framework import Check, EyeFrame, VerifyRun

METRIC = "max rel error vs fx*B/z"


class DisparityCheck(Check):
    names = ("disparity",)
    maps = ("disparity",)

    def declare(self, run: VerifyRun) -> None:
        if not run.rectified:  # a raw pair has correspondence instead
            return
        for eye in EYES:
            run.collector.metric("disparity", eye, METRIC, run.tol.disparity_rel, note=run.no_pixels_note)

    def check_eye(self, frame: EyeFrame) -> None:
        disparity = frame.map("disparity")
        expect = disparity_from_depth(frame.depth, frame.K[0, 0], frame.run.baseline, dtype=np.float64)
        both = frame.surface & np.isfinite(disparity)
        if both.any():
            rel = np.abs(disparity[both].astype(np.float64) - expect[both]) / expect[both]
            frame.add("disparity", METRIC, float(rel.max()), frame.run.tol.disparity_rel)
