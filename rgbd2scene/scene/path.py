"""Camera paths: per-frame poses of the left eye (T_world_cam, OpenCV axes)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class CameraPath:
    """Left-eye poses T_world_cam (F, 4, 4), one per frame, played at ``fps``.

    ``kind`` names the generator (waypoints, scan, orbit, random, static) and ``settings`` holds
    everything needed to regenerate it.
    """

    T_world_cam: np.ndarray
    fps: float = 30.0
    kind: str = "static"
    settings: dict = field(default_factory=dict)

    @property
    def frames(self) -> int:
        return int(self.T_world_cam.shape[0])

    def to_dict(self) -> dict:
        return {"kind": self.kind, "fps": self.fps, "frames": self.frames, "settings": self.settings,
                "T_world_cam": self.T_world_cam.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> CameraPath:
        return cls(np.asarray(d["T_world_cam"], dtype=np.float64).reshape(-1, 4, 4), float(d["fps"]),
                   d.get("kind", "static"), d.get("settings", {}))


def look_at(position, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """T_world_cam (OpenCV axes) of a camera at ``position`` looking at ``target``.

    ``up`` is the world direction that should appear up in the image (OpenCV y points down, so the
    default (0, -1, 0) keeps the capture camera's orientation).
    """
    position = np.asarray(position, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - position
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, dtype=np.float64), z)
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any perpendicular
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, position
    return T


# ------------------------------------------------------------------------------------------------
# Waypoint interpolation and path files

DEFAULT_STANDOFF = 0.04
DEFAULT_SPEED = 0.02  # m/s: a slow, steady endoscope motion (a few pixels of flow per frame at 30 fps)
PATH_KINDS = ("static", "waypoints", "scan", "orbit", "random")
_UP = (0.0, -1.0, 0.0)


def _fail(where: str, message: str):
    from rgbd2scene.errors import UserError

    raise UserError(f"{where}: {message}")


def _vector(value, where: str, what: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(where, f"{what} must be 3 numbers, got {value!r}")
    if a.shape != (3,) or not np.isfinite(a).all():
        _fail(where, f"{what} must be 3 finite numbers, got {value!r}")
    return a


def _pose(value, where: str) -> np.ndarray:
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(where, "T_world_cam must be a 4x4 matrix of numbers")
    if T.shape != (4, 4) or not np.isfinite(T).all():
        _fail(where, f"T_world_cam must be a 4x4 matrix of finite numbers, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        _fail(where, f"T_world_cam's last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        _fail(where, "T_world_cam's rotation part is not a proper rotation (orthonormal, det +1)")
    return T


def _parse_waypoint(w, where: str) -> dict:
    """Normalise one waypoint to {"T": 4x4} or {"position", "look_at", "up"}, plus optional "frame"."""
    if isinstance(w, np.ndarray) or (isinstance(w, list | tuple) and len(w) == 4):
        return {"T": _pose(w, where)}
    if not isinstance(w, dict):
        _fail(where, "a waypoint must be an object with position/look_at or T_world_cam")
    out: dict = {}
    if "frame" in w:
        f = w["frame"]
        if isinstance(f, bool) or not isinstance(f, int | float | np.number) or not np.isfinite(f):
            _fail(where, f"frame must be a number, got {f!r}")
        out["frame"] = float(f)
    if "T_world_cam" in w:
        if "position" in w or "look_at" in w:
            _fail(where, "give either T_world_cam or position/look_at, not both")
        out["T"] = _pose(w["T_world_cam"], where)
        return out
    if "position" not in w or "look_at" not in w:
        missing = [k for k in ("position", "look_at") if k not in w]
        _fail(where, f"waypoint lacks {' and '.join(missing)} (or give T_world_cam)")
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


def _interp_vectors(times: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """C2 cubic spline (natural ends) through (times, values), held constant outside; linear for 2 keys."""
    from scipy.interpolate import CubicSpline

    if len(times) == 1:
        return np.repeat(values[:1], len(t), axis=0)
    tc = np.clip(t, times[0], times[-1])
    if len(times) == 2:
        a = ((tc - times[0]) / (times[1] - times[0]))[:, None]
        return (1 - a) * values[0] + a * values[1]
    return CubicSpline(times, values, axis=0, bc_type="natural")(tc)


def waypoint_path(waypoints, frames: int, fps: float = 30.0, where: str = "waypoints") -> CameraPath:
    """Smooth left-eye path through waypoints.

    Each waypoint is ``{"position": xyz, "look_at": xyz[, "up": xyz]}`` or ``{"T_world_cam": 4x4}``
    (or a bare 4x4 pose), optionally with ``"frame"`` (the frame it is reached at; give it on every
    waypoint or none: by default the waypoints are spread evenly over frames 0 .. frames-1). Positions
    follow a C2 cubic spline (natural ends); with only look-at waypoints the look-at targets and up
    vectors are splined the same way and the camera looks at the interpolated target, otherwise the
    orientations follow a C2 rotation spline (``scipy.spatial.transform.RotationSpline``). The path
    passes exactly through every waypoint at its frame.
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
    wps = [_parse_waypoint(w, f"{where}: waypoint {i}") for i, w in enumerate(waypoints)]
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
        pos = _interp_vectors(times, np.array([w["position"] for w in wps]), t)
        tgt = _interp_vectors(times, np.array([w["look_at"] for w in wps]), t)
        up = _interp_vectors(times, np.array([w["up"] for w in wps]), t)
        d = tgt - pos
        d_len = np.linalg.norm(d, axis=1)
        ok = d_len > 1e-9
        if ok.all():
            d /= d_len[:, None]
            upn = up / np.linalg.norm(up, axis=1, keepdims=True)
            ok = np.linalg.norm(np.cross(d, upn), axis=1) > 1e-6
        if ok.all():
            T = np.stack([look_at(p, q, u) for p, q, u in zip(pos, tgt, up, strict=True)])
            return CameraPath(T, float(fps), "waypoints", {"waypoints": n, "interpolation": "look_at_spline"})

    keys = np.stack([w["T"] if "T" in w else look_at(w["position"], w["look_at"], w["up"]) for w in wps])
    pos = _interp_vectors(times, keys[:, :3, 3], t)
    if n == 1:
        R = np.repeat(keys[:1, :3, :3], frames, axis=0)
    else:
        R = RotationSpline(times, Rotation.from_matrix(keys[:, :3, :3]))(np.clip(t, times[0], times[-1]))
        R = R.as_matrix()
    T = np.tile(np.eye(4), (frames, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, pos
    return CameraPath(T, float(fps), "waypoints", {"waypoints": n, "interpolation": "rotation_spline"})


def load_path_file(path) -> CameraPath:
    """Read a path file: JSON ``{"fps": 30, "frames": 60, "waypoints": [...]}`` (see :func:`waypoint_path`).

    ``frames`` defaults to the number of waypoints and ``fps`` to 30. Raises ``UserError`` naming the file.
    """
    import json
    from pathlib import Path

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
    result = waypoint_path(wps, frames, float(fps), where=where)
    result.settings["file"] = where
    return result


def save_path_file(path, camera_path: CameraPath) -> None:
    """Write a path as a path file with one ``T_world_cam`` waypoint per frame (reloads exactly)."""
    from rgbd2scene.files.atomic import write_json

    write_json(path, {"fps": camera_path.fps, "frames": camera_path.frames, "kind": camera_path.kind,
                      "waypoints": [{"T_world_cam": T.tolist(), "frame": i}
                                    for i, T in enumerate(camera_path.T_world_cam)]})


# ------------------------------------------------------------------------------------------------
# Paths generated from the mesh: scan, orbit, random, static


class _Surface:
    """The mesh seen along the capture direction (+z): an orthographic height map and its valid cells."""

    def __init__(self, rc, cell: float):
        v = rc.vertices
        lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)
        extent = hi - lo
        cell = max(cell, float(extent.max()) / 1024.0, 1e-6)
        nx, ny = (np.ceil(extent / cell).astype(int) + 1).tolist()
        self.rc, self.cell, self.origin = rc, cell, lo
        xs, ys = lo[0] + cell * np.arange(nx), lo[1] + cell * np.arange(ny)
        gx, gy = np.meshgrid(xs, ys)
        z0 = float(v[:, 2].min()) - 1.0
        origins = np.stack([gx, gy, np.full_like(gx, z0)], axis=-1)
        t = rc.cast_rays(origins, np.broadcast_to([0.0, 0.0, 1.0], origins.shape))["t"]
        self.height = z0 + t  # (ny, nx), NaN where no surface
        self.valid = np.isfinite(self.height)

    def to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.rint((np.asarray(xy)[..., :2] - self.origin) / self.cell).astype(int)
        return ij[..., 1], ij[..., 0]  # row, col

    def to_xy(self, rows, cols) -> np.ndarray:
        return self.origin + self.cell * np.stack([np.asarray(cols), np.asarray(rows)], axis=-1).astype(float)

    def inside(self, mask: np.ndarray, xy: np.ndarray) -> np.ndarray:
        r, c = self.to_cell(xy)
        ok = (r >= 0) & (r < mask.shape[0]) & (c >= 0) & (c < mask.shape[1])
        out = np.zeros(r.shape, bool)
        out[ok] = mask[r[ok], c[ok]]
        return out

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        r, c = self.to_cell(xy)
        r = np.clip(r, 0, self.height.shape[0] - 1)
        c = np.clip(c, 0, self.height.shape[1] - 1)
        return self.height[r, c]

    def region(self, half_x: float, half_y: float) -> np.ndarray:
        """Cells whose surrounding rectangle (half sizes in metres) holds only valid cells."""
        from scipy import ndimage

        rx, ry = int(np.ceil(half_x / self.cell)), int(np.ceil(half_y / self.cell))
        return ndimage.minimum_filter(self.valid.astype(np.uint8), size=(2 * ry + 1, 2 * rx + 1),
                                      mode="constant", cval=0).astype(bool)


def _footprint_half(rig, depth: float, tilt_rad: float) -> tuple[float, float]:
    """Half extents (x, y) on a plane at ``depth`` of both eyes' views, tilted by up to ``tilt_rad``."""
    intr = rig.intrinsics
    ax = np.arctan(max(intr.cx + 0.5, intr.width - 0.5 - intr.cx) / intr.fx)
    ay = np.arctan(max(intr.cy + 0.5, intr.height - 0.5 - intr.cy) / intr.fy)
    hx = depth * np.sin(ax) / np.cos(min(ax + tilt_rad, np.radians(85.0))) + rig.baseline
    hy = depth * np.sin(ay) / np.cos(min(ay + tilt_rad, np.radians(85.0)))
    return float(hx), float(hy)


def _rotations(yaw, pitch, roll) -> np.ndarray:
    """Camera orientations (F, 3, 3): the capture orientation turned by small yaw/pitch/roll (radians)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("YXZ", np.stack([yaw, pitch, roll], axis=-1)).as_matrix()


def _place(surface: _Surface, ground_xy: np.ndarray, R: np.ndarray, standoff: float, smooth: float,
           target: np.ndarray | None = None) -> np.ndarray:
    """Poses (F, 4, 4) looking along R[:, :, 2] with the surface ``standoff`` ahead at the image centre.

    The camera starts ``standoff`` before the surface point above ``ground_xy`` (or ``target``) and is
    moved along its view axis until the centre ray meets the visible surface at ``standoff``; the moves
    are smoothed over ``smooth`` frames (Gaussian sigma) so that small bumps do not shake the camera,
    staying within 10 % of the exact standoff (a step in the surface moves the camera with it).
    """
    from scipy.ndimage import gaussian_filter1d

    d = R[:, :, 2]
    if target is None:
        z = surface.height_at(ground_xy)
        target = np.column_stack([ground_xy, z])
    p0 = target - standoff * d
    shift = np.zeros(len(d))
    for _ in range(4):
        t = surface.rc.cast_rays(p0 + shift[:, None] * d, d)["t"]
        step = np.where(np.isfinite(t), t - standoff, 0.0)
        shift += step
        if np.all(np.abs(step) < 1e-6 * standoff):
            break
    if smooth > 0 and len(shift) > 2:  # smooth, but never further than 10 % from the exact standoff
        limit = 0.1 * standoff
        shift = np.clip(gaussian_filter1d(shift, smooth, mode="nearest"), shift - limit, shift + limit)
    T = np.tile(np.eye(4), (len(d), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p0 + shift[:, None] * d
    return T


def _smooth_noise(rng, n: int, frames: int, amplitude: float) -> np.ndarray:
    """Smooth random signal in [-amplitude, amplitude] through n random keys spread over the frames."""
    if amplitude <= 0:
        return np.zeros(frames)
    keys = rng.uniform(-amplitude, amplitude, size=max(n, 2))
    if frames == 1:
        return keys[:1]
    return np.clip(_interp_vectors(np.linspace(0, frames - 1, len(keys)), keys[:, None],
                                   np.arange(frames, dtype=float))[:, 0], -amplitude, amplitude)


def _ease(x: np.ndarray) -> np.ndarray:
    """Smooth start and stop: 0 -> 0, 1 -> 1 with zero slope at both ends."""
    return 0.5 - 0.5 * np.cos(np.pi * np.clip(x, 0.0, 1.0))


def _scan_ground(surface, region, rng, frames, length, rows, row_spacing, angle):
    """Serpentine sweep: ``rows`` parallel lines of ``length`` metres inside ``region``; None if none fits."""
    from scipy import ndimage

    dist = ndimage.distance_transform_edt(region)
    cand_r, cand_c = np.nonzero(region)
    if len(cand_r) == 0:
        return None
    if angle is not None:
        angles = [angle]
    else:
        angles = list(rng.permutation(np.linspace(0, np.pi, 12, endpoint=False)))
    for scale in (1.0, 0.75, 0.5, 0.35, 0.25):
        for a in angles:
            u = np.array([np.cos(a), np.sin(a)])
            w = np.array([-u[1], u[0]])
            pts = []
            for k in range(rows):
                off = (k - (rows - 1) / 2.0) * row_spacing * w
                ends = [-0.5 * length * scale * u + off, 0.5 * length * scale * u + off]
                pts += ends if k % 2 == 0 else ends[::-1]
            pts = np.array(pts)
            seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
            s = np.concatenate([[0.0], np.cumsum(seg)])
            samples = np.linspace(0.0, s[-1], max(4 * frames, 64))
            poly = np.column_stack([np.interp(samples, s, pts[:, 0]), np.interp(samples, s, pts[:, 1])])
            # centres where the whole polyline stays inside the region, the more interior the likelier
            order = rng.permutation(len(cand_r))
            weights = dist[cand_r[order], cand_c[order]]
            order = order[np.argsort(-weights, kind="stable")][: 400]
            for idx in rng.permutation(order)[:200]:
                centre = surface.to_xy(cand_r[idx], cand_c[idx])
                if surface.inside(region, poly + centre).all():
                    arc = _ease(np.linspace(0.0, 1.0, frames)) * s[-1]
                    ground = np.column_stack([np.interp(arc, s, pts[:, 0]), np.interp(arc, s, pts[:, 1])])
                    return ground + centre, a, length * scale
    return None


def _random_ground(surface, region, rng, frames, fps, speed, tries=60):
    """Seeded smooth wander inside ``region``: a spline through a random walk of control points."""
    cand_r, cand_c = np.nonzero(region)
    if len(cand_r) == 0:
        return None
    if frames == 1:
        i = rng.integers(len(cand_r))
        return surface.to_xy(cand_r[i], cand_c[i])[None]
    duration = (frames - 1) / fps
    n_ctrl = int(np.clip(np.ceil(duration / 0.75), 1, 40)) + 1
    step = speed * duration / (n_ctrl - 1)
    times = np.linspace(0, frames - 1, n_ctrl)
    t = np.arange(frames, dtype=float)
    for _ in range(tries):
        i = rng.integers(len(cand_r))
        pts = [surface.to_xy(cand_r[i], cand_c[i])]
        heading = rng.uniform(0, 2 * np.pi)
        for _k in range(n_ctrl - 1):
            for _attempt in range(20):
                h = heading + rng.normal(0.0, np.radians(50.0))
                q = pts[-1] + step * rng.uniform(0.6, 1.4) * np.array([np.cos(h), np.sin(h)])
                if surface.inside(region, q[None])[0]:
                    heading = h
                    pts.append(q)
                    break
            else:
                break
        if len(pts) < n_ctrl:
            continue
        ground = _interp_vectors(times, np.array(pts), t)
        if surface.inside(region, ground).all():
            return ground
    return None


def path_coverage(vertices, triangles, rig, path: CameraPath, scale: float = 1.0, rc=None) -> np.ndarray:
    """Fraction of pixels (F, 2) that see the surface within the rig's clip range, per frame, left/right.

    ``scale`` < 1 checks at a reduced resolution (faster); ``rc`` is a ready ``raycast.Raycaster``
    (then vertices and triangles are not used).
    """
    from rgbd2scene.groundtruth.raycast import raycaster

    rc = rc if rc is not None else raycaster(vertices, triangles)
    intr = rig.intrinsics
    if scale != 1.0:
        intr = intr.resized(max(2, int(round(intr.width * scale))), max(2, int(round(intr.height * scale))))
    K = intr.K
    out = np.zeros((path.frames, 2))
    for f, T in enumerate(path.T_world_cam):
        for eye, pose in enumerate((T, rig.right_pose(T))):
            depth = rc.cast(K, intr.width, intr.height, pose, normals="none")["depth"]
            with np.errstate(invalid="ignore"):
                ok = (depth >= rig.clip_start) & (depth <= rig.clip_end)
            out[f, eye] = ok.mean()
    return out


def make_path(kind: str, vertices=None, triangles=None, rig=None, frames: int = 60, fps: float = 30.0,
              seed: int = 0, standoff: float = DEFAULT_STANDOFF, *, waypoints=None,
              speed: float = DEFAULT_SPEED,
              min_coverage: float = 0.95, check_scale: float = 0.5, smooth: float = 1.5, rc=None,
              **options) -> CameraPath:
    """Camera path of the left eye over the mesh.

    kind
        ``static`` (one pose over the most interior point), ``waypoints`` (``waypoints``: list, or a
        path file name; the mesh is not needed), ``scan`` (a sweep with smooth start and stop; options
        ``length`` in metres, default speed x duration, ``rows`` (1), ``row_spacing`` (half the view
        height), ``angle`` in degrees (seeded random by default), ``tilt`` in degrees (0)), ``orbit``
        (circles the most interior point, looking at it; options ``tilt`` (20 deg), ``turns`` (1)) or
        ``random`` (seeded smooth wander at ``speed`` m/s; options ``max_tilt`` (12 deg), ``max_roll``
        (10 deg)).

    Generated paths look along the capture direction (+z, or tilted from it by at most the tilt), keep
    ``standoff`` metres between the left eye and the visible surface at the image centre, and keep
    both eyes' views on the reconstructed surface: the path stays inside the mesh's footprint
    (orthographic along +z) shrunk by the view's footprint at a depth allowing for relief; every frame
    is then ray cast for both eyes at ``check_scale`` of the rig's resolution and, if any frame sees
    less than ``min_coverage`` surface, the footprint allowance grows and the path is drawn again.
    ``settings`` records everything (and the coverage reached) to regenerate it.
    """
    from rgbd2scene.errors import UserError
    from rgbd2scene.groundtruth.raycast import raycaster

    kind = kind.lower()
    if kind not in PATH_KINDS:
        raise UserError(f"unknown path kind {kind!r}; choose one of {', '.join(PATH_KINDS)}")
    frames = int(frames)
    if frames < 1:
        raise UserError(f"path: frames must be at least 1, got {frames}")
    if not (fps > 0 and np.isfinite(fps)):
        raise UserError(f"path: fps must be positive, got {fps}")
    if kind == "waypoints":
        if waypoints is None:
            raise UserError("path kind 'waypoints' needs waypoints (a list or a path file)")
        if isinstance(waypoints, str) or hasattr(waypoints, "__fspath__"):
            return load_path_file(waypoints)
        return waypoint_path(waypoints, frames, fps)
    if rig is None:
        from rgbd2scene.scene.rig import StereoRig

        rig = StereoRig.endoscope()
    if not (standoff > 0 and np.isfinite(standoff)):
        raise UserError(f"path: standoff must be positive, got {standoff}")
    if standoff <= rig.clip_start or standoff >= rig.clip_end:
        raise UserError(f"path: standoff {standoff} m lies outside the rig's clip range "
                        f"[{rig.clip_start}, {rig.clip_end}] m")
    rc = rc if rc is not None else raycaster(vertices, triangles)
    if not len(rc.triangles):
        raise UserError("path: the mesh has no triangles")
    intr = rig.intrinsics
    view_h = standoff * intr.height / intr.fy
    surface = _Surface(rc, cell=view_h / 16.0)
    if not surface.valid.any():
        raise UserError("path: the mesh has no surface facing the capture direction (+z)")

    opts = dict(options)
    tilt_deg = float(opts.pop("tilt", 20.0 if kind == "orbit" else 0.0))
    max_tilt = float(opts.pop("max_tilt", 12.0))
    max_roll = float(opts.pop("max_roll", 10.0))
    turns = float(opts.pop("turns", 1.0))
    rows = int(opts.pop("rows", 1))
    row_spacing = float(opts.pop("row_spacing", 0.5 * view_h))
    length = opts.pop("length", None)
    angle = opts.pop("angle", None)
    if opts:
        raise UserError(f"path: unknown option(s) for kind {kind!r}: {', '.join(sorted(opts))}")
    checks = [(0.0 <= tilt_deg < 60.0, f"tilt must lie in [0, 60) degrees, got {tilt_deg}"),
              (0.0 <= max_tilt < 60.0, f"max_tilt must lie in [0, 60) degrees, got {max_tilt}"),
              (0.0 <= max_roll <= 180.0, f"max_roll must lie in [0, 180] degrees, got {max_roll}"),
              (rows >= 1, f"rows must be at least 1, got {rows}"),
              (np.isfinite(turns), f"turns must be a number, got {turns}"),
              (speed > 0 and np.isfinite(speed), f"speed must be positive, got {speed}"),
              (length is None or float(length) > 0, f"length must be positive, got {length}"),
              (0.0 < check_scale <= 1.0, f"check_scale must lie in (0, 1], got {check_scale}"),
              (0.0 <= min_coverage <= 1.0, f"min_coverage must lie in [0, 1], got {min_coverage}")]
    for ok, message in checks:
        if not ok:
            raise UserError(f"path: {message}")
    duration = max(frames - 1, 1) / fps
    length = float(length) if length is not None else speed * duration
    tilt_for_region = np.radians({"random": max_tilt, "orbit": tilt_deg}.get(kind, tilt_deg))

    settings = {"seed": int(seed), "standoff": float(standoff), "min_coverage": float(min_coverage)}
    if kind == "scan":
        settings.update(length=length, rows=rows, row_spacing=row_spacing, tilt=tilt_deg)
    elif kind == "orbit":
        settings.update(tilt=tilt_deg, turns=turns)
    elif kind == "random":
        settings.update(speed=speed, max_tilt=max_tilt, max_roll=max_roll)

    from scipy import ndimage

    best = None
    for relief in (1.25, 1.6, 2.0, 2.6, 3.4, 4.5):
        rng = np.random.default_rng(seed)
        region = surface.region(*_footprint_half(rig, standoff * relief, tilt_for_region))
        if not region.any():
            break
        F = frames
        zeros = np.zeros(F)
        if kind in ("static", "orbit"):
            dist = ndimage.distance_transform_edt(region)
            r, c = np.unravel_index(np.argmax(dist), dist.shape)
            centre = surface.to_xy(r, c)
        if kind == "static":
            R = _rotations(zeros, zeros, zeros)
            T = _place(surface, np.tile(centre, (F, 1)), R, standoff, 0.0)
            extra = {"centre": centre.tolist()}
        elif kind == "orbit":
            target = np.array([*centre, surface.height_at(centre[None])[0]])
            phase = rng.uniform(0.0, 2.0 * np.pi)
            phi = phase + 2.0 * np.pi * turns * np.arange(F) / max(F, 1)
            th = np.radians(tilt_deg)
            pos = target + standoff * np.column_stack(
                [np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), -np.full(F, np.cos(th))])
            R = np.stack([look_at(p, target, _UP)[:3, :3] for p in pos])
            T = _place(surface, None, R, standoff, smooth, target=np.tile(target, (F, 1)))
            extra = {"centre": target.tolist(), "phase": float(phase)}
        elif kind == "scan":
            a = None if angle is None else np.radians(float(angle))
            res = _scan_ground(surface, region, rng, F, length, rows, row_spacing, a)
            if res is None:
                continue
            ground, a, used_len = res
            th = np.radians(tilt_deg)
            R = _rotations(np.full(F, th * np.cos(a)), np.full(F, -th * np.sin(a)), zeros)
            T = _place(surface, ground, R, standoff, smooth)
            extra = {"angle": float(np.degrees(a)), "length": float(used_len)}
        else:  # random
            ground = _random_ground(surface, region, rng, F, fps, speed)
            if ground is None:
                continue
            n_keys = int(np.clip(np.ceil(duration / 1.0), 1, 30)) + 1
            yaw = _smooth_noise(rng, n_keys, F, np.radians(max_tilt) / np.sqrt(2))
            pitch = _smooth_noise(rng, n_keys, F, np.radians(max_tilt) / np.sqrt(2))
            roll = _smooth_noise(rng, n_keys, F, np.radians(max_roll))
            T = _place(surface, ground, _rotations(yaw, pitch, roll), standoff, smooth)
            extra = {}
        candidate = CameraPath(T, float(fps), kind, {})
        cov = path_coverage(None, None, rig, candidate, scale=check_scale, rc=rc)
        if best is None or cov.min() > best[1].min():
            best = (candidate, cov, relief, extra)
        if cov.min() >= min_coverage + 0.005:
            break
    if best is None:
        raise UserError(
            f"path: the mesh (footprint {np.ptp(rc.vertices[:, 0]):.3f} x {np.ptp(rc.vertices[:, 1]):.3f} m) "
            f"has no room for a {kind} path of the {intr.width}x{intr.height} view at standoff "
            f"{standoff} m; try a smaller standoff or a shorter path")
    candidate, cov, relief, extra = best
    if cov.min() < min_coverage:
        raise UserError(
            f"path: no {kind} path keeps {min_coverage:.0%} of both views on the mesh at standoff "
            f"{standoff} m (best frame: {cov.min():.1%}); try a smaller standoff or a shorter path")
    settings.update(extra)
    settings.update(relief_allowance=relief, coverage_min=float(cov.min()), coverage_scale=check_scale)
    candidate.settings = settings
    return candidate
