"""Depth hole filling for RGB-D captures (float32 metres, NaN = hole).

``holes``: which invalid pixels lie on the captured surface (enclosure, border band, beyond range) and
the depth steps and shadows across them; ``solvers``: the fills themselves, pure functions on arrays;
``planes``: planes per colour segment, and quadrics per hole, where the capture shows them (``auto``'s guided
holes);
``policy``: :func:`fill_depth`, which applies the one to the other (``auto`` chooses per hole).
"""

from rgbd2scene.reconstruct.fill.holes import HoleMap, classify_holes, highlight_pixels, shadow_pixels, step_runs
from rgbd2scene.reconstruct.fill.planes import planar_fill
from rgbd2scene.reconstruct.fill.policy import FILL_METHODS, FillResult, fill_depth
from rgbd2scene.reconstruct.fill.solvers import (
    clip_to_rim,
    clip_to_surround,
    fill_background,
    fill_biharmonic,
    fill_colorization,
    fill_guided_thin_plate,
    fill_harmonic,
    fill_inpaint,
    fill_nyu_colorization,
    fill_row_background,
)

__all__ = ["FILL_METHODS", "FillResult", "HoleMap", "classify_holes", "clip_to_rim", "clip_to_surround",
           "fill_background",
           "fill_biharmonic", "fill_colorization", "fill_depth", "fill_guided_thin_plate", "fill_harmonic",
           "fill_inpaint", "fill_nyu_colorization", "fill_row_background", "highlight_pixels", "planar_fill",
           "shadow_pixels",
           "step_runs"]
