"""``coverage``: the fraction of pixels with surface (a warning, not a failure, below the tolerance)."""

from __future__ import annotations

from rgbd2scene.verify.framework import Check, EyeFrame


class CoverageCheck(Check):
    names = ("coverage",)
    maps = ("depth",)

    def check_eye(self, frame: EyeFrame) -> None:
        frame.add("coverage", "valid pixels (min frac)", float(frame.surface.mean()), frame.run.tol.coverage_warn,
                  worst="min", warn_only=True)
