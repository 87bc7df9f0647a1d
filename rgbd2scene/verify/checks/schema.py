"""``schema``: every file is what CONVENTIONS.md sections 3-4 say.

Per eye and frame: the RGB PNG is 8-bit RGB of the dataset's size; the npz has every key of the schema with
its dtype and shape; NaN (never a sentinel) where there is no surface, in every map that has NaN there;
flow NaN on the last (forward) / first (backward) frame; segmentation non-zero exactly on surface; unit
normals facing the camera; positive disparity; K and D as in dataset.json; T_world_cam rigid. Per frame: the
right eye is where the rig puts it (a rectified pair: the left eye moved by the baseline along its x axis,
both sharing K; a raw pair: the inverse of [R | T]).
"""

from __future__ import annotations

import numpy as np

from rgbd2scene.conventions import invert_pose
from rgbd2scene.groundtruth.schema import BACKGROUND_DEPTH, SCHEMA
from rgbd2scene.verify.framework import Check, EyeFrame, PairFrame

#: At most this many problem lines per file.
MAX_ISSUES = 8
#: Float maps with NaN where there is no surface, other than depth (which defines the surface).
NAN_MAPS = tuple(k for k, f in SCHEMA.items() if f.nan_where_no_surface and k != "depth")
#: The flow maps and the frame (relative to the last) on which each must be all NaN.
FLOW_BOUNDARY = {"flow_forward": "last", "flow_backward": "first"}
#: Maps that may be NaN on surface pixels too (CONVENTIONS 1.2: where the other eye does not see the point).
MAY_MISS_ON_SURFACE = ("correspondence",)


class SchemaCheck(Check):
    names = ("schema",)
    maps = tuple(SCHEMA)
    checks_broken_files = True

    def check_eye(self, frame: EyeFrame) -> None:
        if frame.gt is None:
            frame.problem(frame.load_error)
            frame.add("schema", "files with issues", 1.0, 0.0)
            return
        _check_rgb(frame)
        issues = list(frame.key_check.issues)
        if frame.usable:
            issues += _check_values(frame)
        frame.add("schema", "files with issues", float(bool(issues)), 0.0)
        for text in issues[:MAX_ISSUES]:
            frame.problem(text)

    def check_pair(self, pair: PairFrame) -> None:
        tol, rig = pair.run.tol, pair.run.rig
        # the baseline along x for a rectified pair; [R | T] inverted for a raw one
        expect = rig.calibration.T_left_right
        T_left_right = invert_pose(pair.left.T_world_cam) @ pair.right.T_world_cam
        pair.add("schema", "both", "right pose vs left + rig (max abs)",
                 float(np.max(np.abs(T_left_right - expect))), tol.pose_m)
        if pair.run.rectified:
            pair.add("schema", "both", "K left vs right (max abs)",
                     float(np.max(np.abs(pair.left.K - pair.right.K))), tol.K_abs)


def _check_rgb(frame: EyeFrame) -> None:
    """The RGB PNG: present, readable, 8-bit with 3 (or 4) channels, the dataset's size."""
    import cv2

    path = frame.paths.rgb
    name = path.relative_to(frame.run.dataset.root)
    height, width = frame.run.shape
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None  # as stored: no conversion
    issue = None
    if img is None:
        issue = f"{'unreadable' if path.is_file() else 'missing'} {name}"
    elif img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        issue = f"{name} is not 8-bit RGB ({img.dtype}, shape {img.shape})"
    elif img.shape[:2] != (height, width):
        issue = f"{name} is {img.shape[1]}x{img.shape[0]}, not {width}x{height}"
    frame.add("schema", "rgb png issues", float(issue is not None), 0.0)
    if issue:
        frame.problem(issue)


def _check_values(frame: EyeFrame) -> list[str]:
    """NaN masks, sentinels, flow on the boundary frames, normals, K and pose of a usable file; returns issues."""
    gt, tol, last = frame.gt, frame.run.tol, frame.run.last
    issues = []
    depth, surface = frame.depth, frame.surface
    with np.errstate(invalid="ignore"):
        sentinels = int(np.sum(np.isfinite(depth) & ~surface)) + int(np.isinf(depth).sum())
    if sentinels:
        issues.append(f"depth has {sentinels} sentinel/inf values (0, negative, >= {BACKGROUND_DEPTH:g}): use NaN")
    mismatch = []
    for key in NAN_MAPS:
        a = gt.get(key)
        if a is None or a.shape[:2] != frame.run.shape or not np.issubdtype(a.dtype, np.floating):
            continue
        fin = np.all(np.isfinite(a), axis=-1) if a.ndim == 3 else np.isfinite(a)
        any_nan = np.any(np.isnan(a), axis=-1) if a.ndim == 3 else np.isnan(a)
        n_inf = int(np.isinf(a).sum())
        if n_inf:
            issues.append(f"{key} has {n_inf} infinite values")
        if key in FLOW_BOUNDARY or key in MAY_MISS_ON_SURFACE:
            boundary = FLOW_BOUNDARY.get(key)
            if boundary and frame.index == (last if boundary == "last" else 0):
                if fin.any():
                    issues.append(f"{key} must be NaN on the {boundary} frame ({int(fin.sum())} finite pixels)")
                continue
            # flow may be missing on surface (reported by the flow check), correspondence where the other
            # eye does not see the point (the correspondence check)
            stray = fin & ~surface
            mismatch.append(stray.mean())
            if stray.any():
                issues.append(f"{key} has values on {int(stray.sum())} pixels without surface")
            continue
        bad = fin != surface
        partial = any_nan & fin if a.ndim == 3 else np.zeros_like(fin)
        mismatch.append((bad | partial).mean())
        if bad.any():
            issues.append(f"{key}: NaN mask differs from depth's on {int(bad.sum())} pixels")
        if key == "disparity":
            with np.errstate(invalid="ignore"):
                nonpos = int(np.sum(fin & (a <= 0)))
            if nonpos:
                issues.append(f"disparity is not positive on {nonpos} pixels")
                sentinels += nonpos
        if key == "normals":
            sentinels += _check_normals(frame, a, fin & surface, issues)
    seg = gt.get("segmentation")
    if seg is not None and seg.shape == frame.run.shape:
        bad = (seg != 0) != surface
        mismatch.append(bad.mean())
        if bad.any():
            issues.append(f"segmentation: nonzero ids differ from the depth's surface on {int(bad.sum())} px")
    frame.add("schema", "NaN/id mask mismatch (frac)", max(mismatch) if mismatch else 0.0, 0.0)
    frame.add("schema", "sentinel values (count)", float(sentinels), 0.0)
    camera = frame.run.rig.camera(frame.eye)
    frame.add("schema", "K vs dataset.json (max abs)", float(np.max(np.abs(frame.K - camera.K))), tol.K_abs)
    D = gt.get("D")
    if D is not None and D.ndim == 1:
        want = camera.distortion
        off = float(np.max(np.abs(D - want))) if D.shape == want.shape else float("inf")
        frame.add("schema", "D vs dataset.json (max abs)", off, tol.K_abs)
    T = frame.T_world_cam
    R = T[:3, :3]
    rigid = float(max(np.max(np.abs(R.T @ R - np.eye(3))), abs(np.linalg.det(R) - 1),
                      np.max(np.abs(T[3] - [0, 0, 0, 1]))))
    frame.add("schema", "T_world_cam rigidity error", rigid, tol.pose_rigidity)
    return issues


def _check_normals(frame: EyeFrame, normals: np.ndarray, pixels: np.ndarray, issues: list[str]) -> int:
    """Unit length and facing the camera (n . ray < 0) on ``pixels``; returns the count of zero normals."""
    if not pixels.any():
        return 0
    n = normals[pixels].astype(np.float64)
    length = np.linalg.norm(n, axis=-1)
    frame.add("schema", "normals |n|-1 (max)", float(np.max(np.abs(length - 1))), frame.run.tol.normal_unit)
    zero = int(np.sum(length < 1e-6))
    if zero:
        issues.append(f"normals are zero on {zero} pixels: use NaN where there is no surface")
    facing = np.sum(n * frame.rays[pixels], axis=-1) >= 0
    frame.add("schema", "normals not facing camera (frac)", float(facing.mean()), frame.run.tol.normal_facing)
    return zero
