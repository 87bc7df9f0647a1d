"""Tracks through waypoints (splines) and path files; for the camera's path or any object's track.

A path file is JSON ``{"fps": 30, "frames": 60, "waypoints": [...]}``; a waypoint is ``{"position": xyz,
"look_at": xyz[, "up": xyz]}`` or a full pose under the track's ``pose_key`` (``T_world_cam`` for the
camera, ``T_world_obj`` for an object), optionally with ``"frame"``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rgbd2scene.files.atomic import write_json
from rgbd2scene.scene.paths.track import CameraPath, Track, look_at

_UP = (0.0, -1.0, 0.0)  # the capture camera's up (OpenCV y points down), as in look_at


def _fail(where: str, message: str):
    raise ValueError(f"{where}: {message}")


def _vector(value, where: str, what: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(where, f"{what} must be 3 numbers, got {value!r}")
    if a.shape != (3,) or not np.isfinite(a).all():
        _fail(where, f"{what} must be 3 finite numbers, got {value!r}")
    return a


def pose_matrix(value, where: str, pose_key: str = "pose") -> np.ndarray:
    """``value`` as a rigid 4x4 pose (float64): finite, last row [0, 0, 0, 1], a proper rotation
    (orthonormal to 1e-4, det +1); ``ValueError`` starting with ``where`` otherwise."""
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(where, f"{pose_key} must be a 4x4 matrix of numbers")
    if T.shape != (4, 4) or not np.isfinite(T).all():
        _fail(where, f"{pose_key} must be a 4x4 matrix of finite numbers, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        _fail(where, f"{pose_key}'s last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        _fail(where, f"{pose_key}'s rotation part is not a proper rotation (orthonormal, det +1)")
    return T


def _parse_waypoint(w, where: str, pose_key: str) -> dict:
    """Normalise one waypoint to {"T": 4x4} or {"position", "look_at", "up"}, plus optional "frame"."""
    if isinstance(w, np.ndarray) or (isinstance(w, list | tuple) and len(w) == 4):
        return {"T": pose_matrix(w, where, pose_key)}
    if not isinstance(w, dict):
        _fail(where, f"a waypoint must be an object with position/look_at or {pose_key}")
    out: dict = {}
    if "frame" in w:
        f = w["frame"]
        if isinstance(f, bool) or not isinstance(f, int | float | np.number) or not np.isfinite(f):
            _fail(where, f"frame must be a number, got {f!r}")
        out["frame"] = float(f)
    if pose_key in w:
        if "position" in w or "look_at" in w:
            _fail(where, f"give either {pose_key} or position/look_at, not both")
        out["T"] = pose_matrix(w[pose_key], where, pose_key)
        return out
    if "position" not in w or "look_at" not in w:
        missing = [k for k in ("position", "look_at") if k not in w]
        _fail(where, f"waypoint lacks {' and '.join(missing)} (or give {pose_key})")
    p = _vector(w["position"], where, "position")
    q = _vector(w["look_at"], where, "look_at")
    up = _vector(w.get("up", _UP), where, "up")
    if np.linalg.norm(q - p) < 1e-9:
        _fail(where, "look_at equals position")
    if np.linalg.norm(up) < 1e-9:
        _fail(where, "up must not be zero")
    d = (q - p) / np.linalg.norm(q - p)
    if np.linalg.norm(np.cross(d, up / np.linalg.norm(up))) < 1e-6:
        _fail(where, "the view direction (look_at - position) is parallel to up")
    out.update(position=p, look_at=q, up=up / np.linalg.norm(up))
    return out


def interpolate_keys(times: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Values (len(t), ...) at times ``t`` of keys ``values`` at ``times``.

    A C2 cubic spline (natural ends) through the keys, linear for 2 keys, held constant outside them.
    """
    from scipy.interpolate import CubicSpline

    if len(times) == 1:
        return np.repeat(values[:1], len(t), axis=0)
    tc = np.clip(t, times[0], times[-1])
    if len(times) == 2:
        a = ((tc - times[0]) / (times[1] - times[0]))[:, None]
        return (1 - a) * values[0] + a * values[1]
    return CubicSpline(times, values, axis=0, bc_type="natural")(tc)


def waypoint_path(waypoints, frames: int, fps: float = 30.0, where: str = "waypoints",
                  track_type: type[Track] = CameraPath) -> Track:
    """Smooth track through waypoints (the camera's left eye by default; ``track_type`` picks another).

    Each waypoint is ``{"position": xyz, "look_at": xyz[, "up": xyz]}`` or ``{pose_key: 4x4}`` (or a bare
    4x4 pose), optionally with ``"frame"`` (the frame it is reached at; give it on every waypoint or none:
    by default the waypoints are spread evenly over frames 0 .. frames-1). Positions follow a C2 cubic
    spline (natural ends); with only look-at waypoints the look-at targets and up vectors are splined the
    same way and the track looks at the interpolated target, otherwise the orientations follow a C2
    rotation spline (``scipy.spatial.transform.RotationSpline``). The track passes exactly through every
    waypoint at its frame. Raises ``ValueError`` starting with ``where``.
    """
    from scipy.spatial.transform import Rotation, RotationSpline

    frames = int(frames)
    if frames < 1:
        _fail(where, f"frames must be at least 1, got {frames}")
    if not (fps > 0 and np.isfinite(fps)):
        _fail(where, f"fps must be positive, got {fps}")
    if isinstance(waypoints, np.ndarray) and waypoints.ndim == 3:
        waypoints = list(waypoints)
    if not isinstance(waypoints, list | tuple) or not waypoints:
        _fail(where, "need a non-empty list of waypoints")
    wps = [_parse_waypoint(w, f"{where}: waypoint {i}", track_type.pose_key) for i, w in enumerate(waypoints)]
    n = len(wps)
    with_frame = ["frame" in w for w in wps]
    if any(with_frame) and not all(with_frame):
        _fail(where, "give \"frame\" on every waypoint or on none")
    if all(with_frame):
        times = np.array([w["frame"] for w in wps])
        if np.any(np.diff(times) <= 0):
            _fail(where, f"waypoint frames must increase strictly, got {times.tolist()}")
        if times[0] < 0 or times[-1] > frames - 1:
            _fail(where, f"waypoint frames must lie in 0..{frames - 1}, got {times.tolist()}")
    elif n == 1:
        times = np.zeros(1)
    else:
        if frames < n:
            _fail(where, f"{n} waypoints need at least {n} frames, got {frames}")
        times = np.linspace(0.0, frames - 1, n)
    t = np.arange(frames, dtype=np.float64)

    if all("T" not in w for w in wps):
        pos = interpolate_keys(times, np.array([w["position"] for w in wps]), t)
        tgt = interpolate_keys(times, np.array([w["look_at"] for w in wps]), t)
        up = interpolate_keys(times, np.array([w["up"] for w in wps]), t)
        d = tgt - pos
        d_len = np.linalg.norm(d, axis=1)
        ok = d_len > 1e-9
        if ok.all():
            d /= d_len[:, None]
            upn = up / np.linalg.norm(up, axis=1, keepdims=True)
            ok = np.linalg.norm(np.cross(d, upn), axis=1) > 1e-6
        if ok.all():
            T = np.stack([look_at(p, q, u) for p, q, u in zip(pos, tgt, up, strict=True)])
            return track_type(T, float(fps), "waypoints", {"waypoints": n, "interpolation": "look_at_spline"})

    keys = np.stack([w["T"] if "T" in w else look_at(w["position"], w["look_at"], w["up"]) for w in wps])
    pos = interpolate_keys(times, keys[:, :3, 3], t)
    if n == 1:
        R = np.repeat(keys[:1, :3, :3], frames, axis=0)
    else:
        R = RotationSpline(times, Rotation.from_matrix(keys[:, :3, :3]))(np.clip(t, times[0], times[-1]))
        R = R.as_matrix()
    T = np.tile(np.eye(4), (frames, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, pos
    return track_type(T, float(fps), "waypoints", {"waypoints": n, "interpolation": "rotation_spline"})


def load_path_file(path, track_type: type[Track] = CameraPath) -> Track:
    """Read a path file: JSON ``{"fps": 30, "frames": 60, "waypoints": [...]}`` (see :func:`waypoint_path`).

    ``frames`` defaults to the number of waypoints and ``fps`` to 30. Raises ``ValueError`` naming the file.
    """
    path = Path(path)
    where = str(path)
    if not path.is_file():
        _fail(where, "path file not found")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        _fail(where, f"not a readable JSON path file ({exc})")
    if not isinstance(data, dict):
        _fail(where, "a path file must hold a JSON object with \"waypoints\"")
    unknown = set(data) - {"fps", "frames", "waypoints", "comment", "kind"}
    if unknown:
        _fail(where, f"unknown key(s) {sorted(unknown)} (allowed: fps, frames, waypoints, comment)")
    wps = data.get("waypoints")
    if not isinstance(wps, list) or not wps:
        _fail(where, "\"waypoints\" must be a non-empty list")
    frames = data.get("frames", len(wps))
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        _fail(where, f"\"frames\" must be a positive integer, got {frames!r}")
    fps = data.get("fps", 30.0)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not (np.isfinite(fps) and fps > 0):
        _fail(where, f"\"fps\" must be a positive number, got {fps!r}")
    result = waypoint_path(wps, frames, float(fps), where=where, track_type=track_type)
    result.settings["file"] = where
    return result


def save_path_file(path, track: Track) -> None:
    """Write a track as a path file with one pose waypoint per frame (reloads exactly)."""
    write_json(path, {"fps": track.fps, "frames": track.frames, "kind": track.kind,
                      "waypoints": [{track.pose_key: T.tolist(), "frame": i} for i, T in enumerate(track.poses)]})
