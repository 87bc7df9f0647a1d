"""``segmentation``: every pixel's instance id against the id of the part the oracle's ray hits there.

Off a thin band around the silhouettes of the id map (where a pixel centre may fall either side of an edge
in float32), the ids must agree exactly: a blended, shifted or mislabelled id shows here. Needs an oracle
that knows which part each triangle belongs to (the scene model).
"""

from __future__ import annotations

import numpy as np

from rgbd2scene.dataset.layout import EYES
from rgbd2scene.verify.checks.depth import silhouette_band
from rgbd2scene.verify.framework import Check, EyeFrame, VerifyRun


class SegmentationCheck(Check):
    names = ("segmentation",)
    maps = ("segmentation",)
    needs_oracle = True

    def declare(self, run: VerifyRun) -> None:
        for eye in EYES:
            run.collector.metric("segmentation", eye, "ids differing from the scene off edges (frac)",
                                 run.tol.id_mismatch, note=run.no_pixels_note)

    def check_eye(self, frame: EyeFrame) -> None:
        ref = frame.cast.instance_ids
        seg = frame.map("segmentation")
        if ref is None or seg is None:
            return
        consider = frame.oracle_pixels
        edges = np.zeros(seg.shape, bool)
        for oid in np.union1d(np.unique(seg), np.unique(ref)):
            edges |= silhouette_band(seg == oid, frame.run.tol.mask_band_px)
        judged = consider & ~edges
        if judged.any():
            wrong = (seg != ref) & judged
            frame.add("segmentation", "ids differing from the scene off edges (frac)",
                      float(wrong.sum() / judged.sum()), frame.run.tol.id_mismatch)
