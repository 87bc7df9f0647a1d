"""Self-consistency checks of a rendered stereo dataset (``rgbd2scene verify DATASET``).

Each check compares the ground truth on disk (CONVENTIONS.md sections 3-4, read through
``dataset.Dataset`` and the one schema ``groundtruth.schema``) with an independent computation:

- ``schema``: keys, dtypes and shapes of every npz, NaN (never a sentinel) where there is no surface,
  unit normals facing the camera, positive disparity, K and the rig (right = left + baseline along x).
- ``coverage``: fraction of pixels with surface (a warning, not a failure, below 95 %).
- ``depth``: against the scene oracle's ray cast at the recorded K and pose (median / p99 error over
  pixels valid in both, and the valid masks, allowing a thin band of mismatch at silhouettes).
- ``normals``: against the oracle's interpolated angle-weighted vertex normals at the ray-cast hits (what
  a smooth-shaded render shows); the angle to the face normal is reported for information.
- ``disparity``: equals fx*B/z.
- ``flow_fwd`` / ``flow_bwd``: against reprojecting depth with K and the poses of the next / previous
  frame (static objects), and NaN on the last / first frame.
- ``stereo``: left/right depth agree through the disparity (left (u, v) sees what right (u - d, v) sees)
  wherever the other eye is not occluded.
- ``occlusion``: ``occluded_forward`` / ``occluded_backward`` agree with reprojecting depth into the
  next / previous frame.

``verify_dataset`` returns a :class:`VerifyReport` (``report.ok``); ``format_report`` prints it. With
``error_maps=DIR`` it also draws, per eye, the worst frame of the depth check (and of the flow check, where
that is another frame) as a PNG of labelled panels (``error_maps.render_error_map``).

Where things are
----------------
``driver.py`` (the loop over frames and eyes), ``framework.py`` (:class:`Tolerances`, the ``Check`` base,
the per-frame views ``EyeFrame`` / ``PairFrame``, the collector), ``oracle.py`` (``SceneOracle``: what eye E
sees at frame f, by ray casting the scene model), ``checks/`` (one module per check), ``report.py``,
``error_maps.py``.

Adding a check (a moving-object or a deformation check, say) is one new module in ``checks/`` with a
``Check`` subclass and one line in ``checks.CHECKS``; see ``checks/__init__.py`` and ``framework.py``.
"""

from rgbd2scene.verify.driver import verify_dataset
from rgbd2scene.verify.error_maps import ERROR_PANELS, ErrorPanel, FrameErrors, error_map_layout, render_error_map
from rgbd2scene.verify.framework import Check, CheckResult, EyeFrame, PairFrame, Tolerances
from rgbd2scene.verify.oracle import RayCast, SceneOracle, StaticMeshOracle
from rgbd2scene.verify.report import VerifyReport, format_report

__all__ = ["ERROR_PANELS", "Check", "CheckResult", "ErrorPanel", "EyeFrame", "FrameErrors", "PairFrame", "RayCast",
           "SceneOracle", "StaticMeshOracle", "Tolerances", "VerifyReport", "error_map_layout", "format_report",
           "render_error_map", "verify_dataset"]
