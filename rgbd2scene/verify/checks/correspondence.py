"""``correspondence``: a raw pair's correspondence against depth, poses, K and D (CONVENTIONS 1.2).

Each pixel's surface point (its depth along the pixel's own ray of this eye's camera, distortion
included) is moved into the other eye's frame by the two recorded poses and projected by the other eye's
camera: the correspondence must point there (endpoint error, as for flow). And it must be NaN exactly where
the other eye does not see the point: the other eye's depth around the projection is clearly in front of
the point, or the projection leaves its image (the same reference as the occlusion check).
"""

from __future__ import annotations

import numpy as np

from rgbd2scene.conventions import invert_pose, pixel_grid, transform_points
from rgbd2scene.verify.checks.occlusion import occlusion_reference
from rgbd2scene.verify.framework import Check, PairFrame, VerifyRun, median_p99

#: report label -> (source eye, other eye)
PAIRS = {"L->R": ("left", "right"), "R->L": ("right", "left")}


class CorrespondenceCheck(Check):
    names = ("correspondence",)
    maps = ("correspondence",)

    def declare(self, run: VerifyRun) -> None:
        if run.rectified:
            return
        for label in PAIRS:
            run.collector.metric("correspondence", label, "median endpoint error", run.tol.flow_median_px,
                                 unit="px", note=run.no_pixels_note)
            run.collector.metric("correspondence", label, "visibility contradicting geometry (frac)",
                                 run.tol.occlusion_disagree, note=run.no_pixels_note)

    def check_pair(self, pair: PairFrame) -> None:
        tol = pair.run.tol
        eyes = {"left": pair.left, "right": pair.right}
        for label, (src, dst) in PAIRS.items():
            a, b = eyes[src], eyes[dst]
            c = a.map("correspondence")
            if c is None:
                continue
            surface = a.surface  # both eyes at the same frame: moving objects are where the depth says
            points = transform_points(a.T_world_cam, a.camera.backproject(np.where(surface, a.depth, np.nan)))
            u, v = b.camera.project(transform_points(invert_pose(b.T_world_cam), points))
            gu, gv = pixel_grid(*pair.run.shape)
            ref = np.stack([u - gu, v - gv], axis=-1)
            have = np.all(np.isfinite(c), axis=-1)
            both = have & np.all(np.isfinite(ref), axis=-1) & surface
            if both.any():
                epe = np.linalg.norm(c[both].astype(np.float64) - ref[both], axis=-1)
                med, p99 = median_p99(epe)
                pair.add("correspondence", label, "median endpoint error", med, tol.flow_median_px, unit="px")
                pair.add("correspondence", label, "p99 endpoint error", p99, tol.flow_p99_px, unit="px")
            visible, hidden = occlusion_reference(points, b.camera, b.T_world_cam, b.depth, tol.occlusion_rel)
            wrong = ((~have & visible) | (have & hidden)) & surface
            if surface.any():
                pair.add("correspondence", label, "visibility contradicting geometry (frac)",
                         float(wrong.sum() / surface.sum()), tol.occlusion_disagree)
            stray = have & ~a.surface
            pair.add("correspondence", label, "values without surface (count)", float(stray.sum()), 0.0)
