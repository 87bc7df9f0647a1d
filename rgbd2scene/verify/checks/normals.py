"""``normals``: the normal map against the scene oracle's normals at the ray-cast hits.

With smooth shading (the default) the oracle interpolates angle-weighted vertex normals, what a
smooth-shaded render shows; the angle to the face normals is reported for information (a flat-shaded
render matches those). Pixels with surface in both that the oracle models count.
"""

from __future__ import annotations

import numpy as np

from rgbd2scene.dataset.layout import EYES
from rgbd2scene.verify.error_maps import ErrorPanel, pixel_states
from rgbd2scene.verify.framework import Check, EyeFrame, VerifyRun, median_p99
from rgbd2scene.verify.report import fmt


class NormalsCheck(Check):
    names = ("normals",)
    maps = ("normals",)
    needs_oracle = True

    def declare(self, run: VerifyRun) -> None:
        for eye in EYES:
            run.collector.metric("normals", eye, f"median angle vs {run.oracle.shading} normals",
                                 run.tol.normal_median_deg, unit="deg", note=run.no_pixels_note)

    def check_eye(self, frame: EyeFrame) -> None:
        consider = frame.oracle_pixels
        if not consider.any():
            return
        tol, shading, cast, normals = frame.run.tol, frame.run.oracle.shading, frame.cast, frame.map("normals")
        n_fin = np.all(np.isfinite(normals), axis=-1)
        compared = frame.surface & cast.hit & consider & n_fin
        med = p99 = float("nan")
        if compared.any():
            n = normals[compared].astype(np.float64)
            ang = angle_deg(n, cast.normals[compared].astype(np.float64))
            med, p99 = median_p99(ang)
            frame.add("normals", f"median angle vs {shading} normals", med, tol.normal_median_deg, unit="deg")
            frame.add("normals", f"p99 angle vs {shading} normals", p99, tol.normal_p99_deg, unit="deg")
            if cast.face_normals is not None:
                face_ang = angle_deg(n, cast.face_normals[compared].astype(np.float64))
                frame.add("normals", "median angle vs face normals", float(np.nanmedian(face_ang)), None, unit="deg")
        if frame.errors is not None:
            value = np.full(frame.run.shape, np.nan, np.float32)
            note = "no pixels to compare"
            if compared.any():
                value[compared] = ang
                note = f"median {fmt(med, 'deg')}, p99 {fmt(p99, 'deg')}"
            state = pixel_states(frame.surface & n_fin, cast.hit & np.all(np.isfinite(cast.normals), axis=-1), consider)
            frame.errors.panels["normals"] = ErrorPanel(value, state, f"normal angle error vs {shading} normals", note)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between the vectors (..., 3) of ``a`` and ``b`` (normalised here)."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))
