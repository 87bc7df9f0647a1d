"""Stereo benchmark on a dataset (``rgbd2scene evaluate``): methods, depth metrics after Eigen et al., reports.

``evaluate(path, out, options)`` scores SGBM, ELAS, the ground truth itself or external predictions on every
left/right pair of a dataset folder, or of each ``done`` sequence of a batch ROOT (one table per split). A raw
(distorted) pair is matched after rectification and scored at its own pixels (:mod:`rgbd2scene.evaluate.grid`).
"""

from rgbd2scene.evaluate.methods import BUILTIN, DisparityRange, build_methods
from rgbd2scene.evaluate.metrics import METRICS, depth_metrics, fill_invalid, score_frame, summarize
from rgbd2scene.evaluate.run import EvaluationOptions, EvaluationResult, evaluate

__all__ = ["BUILTIN", "METRICS", "DisparityRange", "EvaluationOptions", "EvaluationResult", "build_methods",
           "depth_metrics", "evaluate", "fill_invalid", "score_frame", "summarize"]
