"""The built-in instrument's default motion: per frame, a world pose of the instrument and of every part.

How it is made (seeded, any camera path):

1. **Where the tip is looked at.** A smooth drift of image positions in the left eye (a spline through
   random keys every ``drift_period_s`` seconds, ``view_margin`` of the image size away from its borders),
   so the tip stays in both views whatever the path does.
2. **Over the tissue.** Under each position the left eye's pixel ray meets the tissue (ray cast of the mesh);
   the tip sits ``hover`` metres (planar depth) in front of that surface point, smoothed over time.
3. **Through a trocar.** The shaft pivots about a fixed remote centre of motion above and to the side of the
   tissue the camera sees in the middle frame (``trocar_distance`` metres away, ``trocar_angle_deg`` off the
   optical axis, towards ``trocar_azimuth_deg`` in the image: 0 from the right, 90 from the bottom; by
   default seeded within 35 degrees of the left or the right side, where the image is wider), so the
   instrument's axis is the line from the trocar to the tip, and the tip's image positions keep 20 % of the
   image away from that side (the shaft crosses the view). Its hinge axis turns with the view (the jaws
   open across the image) plus a slow seeded roll.
4. **Entering.** In the first ``entry_fraction`` of the frames the tip slides in along the shaft from
   where it is outside both views (an instrument is pushed in through its trocar).
5. **Clear of the tissue.** Rays are cast along the shaft (from the trocar to the tip) and along each jaw
   (from the hinge to its end), on a ring of radius part radius + ``clearance`` around the axis and on the
   axis: the tissue must not be met before the part's end plus ``clearance``. Frames where it is are
   lifted towards the camera along the same pixel ray (the tip keeps its image position) until clear, and
   the lifts are smoothed. If a trocar direction cannot be made clear, or brings the shaft within 5 mm of an
   eye, the next direction (45 degrees on) is tried.
6. **Jaws** open and close smoothly: ``jaw_open_deg * (1 - cos(2 pi t / jaw_period_s + phase)) / 2``.

The result records how many frames see the tip in both eyes (inside the image and not hidden by the
tissue) and the smallest clearance found.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from rgbd2scene.conventions import invert_pose, transform_points
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.scene.objects.instrument import Instrument
from rgbd2scene.scene.paths.track import CameraPath
from rgbd2scene.scene.paths.waypoints import interpolate_keys
from rgbd2scene.scene.rig import StereoRig

#: Rays on the ring around each axis (plus one on the axis).
RING_RAYS = 12
#: How far the shaft's axis must stay from either eye, beyond the shaft radius (metres).
EYE_DISTANCE = 0.005
#: Lift step (metres) while clearing the tissue, and the smallest share of the planned depth the tip may
#: come to (the rest of the way to the camera is not used).
LIFT_STEP = 0.0005
MIN_DEPTH_SHARE = 0.4
#: How far (fraction of the image size) the tip's image positions are moved away from the trocar's side.
TARGET_SHIFT = 0.2


@dataclass(frozen=True)
class MotionOptions:
    """Settings of the default motion (see the module docstring); ``seed`` None: the scene's seed."""

    seed: int | None = None
    entry_fraction: float = 0.12
    hover: float = 0.004
    clearance: float = 0.0015
    jaw_open_deg: float = 50.0
    jaw_period_s: float = 2.0
    roll_deg: float = 15.0
    view_margin: float = 0.25
    drift_period_s: float = 1.5
    trocar: tuple[float, float, float] | None = None
    trocar_distance: float = 0.10
    trocar_angle_deg: float = 65.0
    trocar_azimuth_deg: float | None = None

    def __post_init__(self):
        checks = [(0.0 <= self.entry_fraction <= 0.5,
                   f"entry_fraction must lie in [0, 0.5], got {self.entry_fraction}"),
                  (self.hover > 0, f"hover must be positive, got {self.hover}"),
                  (self.clearance >= 0, f"clearance must not be negative, got {self.clearance}"),
                  (0.0 <= self.jaw_open_deg <= 80.0, f"jaw_open_deg must lie in [0, 80], got {self.jaw_open_deg}"),
                  (self.jaw_period_s > 0, f"jaw_period_s must be positive, got {self.jaw_period_s}"),
                  (0.0 <= self.view_margin < 0.5, f"view_margin must lie in [0, 0.5), got {self.view_margin}"),
                  (self.drift_period_s > 0, f"drift_period_s must be positive, got {self.drift_period_s}"),
                  (self.trocar_distance > 0, f"trocar_distance must be positive, got {self.trocar_distance}"),
                  (0.0 < self.trocar_angle_deg < 85.0,
                   f"trocar_angle_deg must lie in (0, 85), got {self.trocar_angle_deg}")]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)
        if self.trocar is not None and (len(self.trocar) != 3 or not np.isfinite(self.trocar).all()):
            raise ValueError(f"trocar must be 3 finite numbers (metres, world frame), got {self.trocar}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["trocar"] = None if self.trocar is None else list(self.trocar)
        return d


@dataclass
class InstrumentTrack:
    """The default motion of one instrument over the frames of a camera path."""

    poses: np.ndarray  # (F, 4, 4) T_world_instrument
    jaw_angle: np.ndarray  # (F,) radians between the jaws
    tip: np.ndarray  # (F, 3) world
    trocar: np.ndarray  # (3,) world
    in_view: np.ndarray  # (F,) bool: the tip is inside both images and not hidden by the tissue
    clearance: np.ndarray  # (F,) metres: the smallest free length found by the rays beyond each part's end
    settings: dict = field(default_factory=dict)

    def part_poses(self, instrument: Instrument) -> dict[str, np.ndarray]:
        """Part name -> T_world_part (F, 4, 4) float64."""
        out = {"shaft": self.poses.copy(), "wrist": self.poses.copy()}
        for name, offset in instrument.jaw_offsets(self.jaw_angle).items():
            out[name] = self.poses @ offset
        return out

    @property
    def in_view_fraction(self) -> float:
        return float(self.in_view.mean()) if len(self.in_view) else 0.0


def target_pixels(rng: np.random.Generator, frames: int, fps: float, width: int, height: int,
                  margin: float, drift_period_s: float, away=(0.0, 0.0)) -> np.ndarray:
    """(F, 2) left-eye pixel positions (u, v): a smooth spline through random keys inside the image less
    ``margin`` of its size at each border, the keys shifted by ``away`` (fractions of the image size) inside
    that region."""
    duration = max(frames - 1, 1) / fps
    n_keys = int(np.ceil(duration / drift_period_s)) + 1
    size = np.array([width - 1, height - 1], dtype=np.float64)
    lo, hi = margin * size, (1 - margin) * size
    keys = lo + rng.uniform(size=(max(n_keys, 2), 2)) * (hi - lo)
    keys = np.clip(keys + np.asarray(away) * size, lo, hi)
    times = np.linspace(0.0, max(frames - 1, 1), len(keys))
    return np.clip(interpolate_keys(times, keys, np.arange(frames, dtype=np.float64)), lo, hi)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _pixel_rays_world(path: CameraPath, camera: Camera, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Origins (F, 3) and world directions (F, 3) with unit camera z of the left eye's rays through ``uv``."""
    T = np.asarray(path.T_world_cam, dtype=np.float64)
    x, y = camera.undistort(uv[:, 0], uv[:, 1])
    rays = np.column_stack([x, y, np.ones(len(uv))])
    return T[:, :3, 3], np.einsum("fij,fj->fi", T[:, :3, :3], rays)


def _fill_gaps(values: np.ndarray) -> np.ndarray:
    ok = np.isfinite(values)
    if not ok.any():
        raise ValueError("the tissue is not under any of the instrument's target pixels")
    idx = np.arange(len(values))
    return np.interp(idx, idx[ok], values[ok])


def _planned_depths(rc, origins: np.ndarray, directions: np.ndarray, hover: float) -> np.ndarray:
    """Tip depths (F,): ``hover`` before the tissue under each pixel ray, smoothed over time, never deeper."""
    from scipy.ndimage import gaussian_filter1d, minimum_filter1d

    surface = _fill_gaps(rc.cast_rays(origins, directions)["t"])
    if len(surface) < 3:
        return surface - hover
    smooth = gaussian_filter1d(minimum_filter1d(surface, 5, mode="nearest"), 1.5, mode="nearest") - hover
    return np.minimum(smooth, surface - hover)


def trocar_point(rc, path: CameraPath, options: MotionOptions, azimuth_rad: float) -> np.ndarray:
    """The remote centre of motion: ``trocar_distance`` from the tissue at the middle frame's image centre,
    ``trocar_angle_deg`` off its optical axis (towards the camera), towards ``azimuth_rad`` in the image."""
    if options.trocar is not None:
        return np.asarray(options.trocar, dtype=np.float64)
    T = np.asarray(path.T_world_cam[path.frames // 2], dtype=np.float64)
    depth = rc.centre_depth(T)
    if not np.isfinite(depth):
        depth = float(np.nanmedian(rc.cast_rays(path.T_world_cam[:, :3, 3], path.T_world_cam[:, :3, 2])["t"]))
    if not np.isfinite(depth):
        raise ValueError("the camera path never looks at the tissue: no place for the instrument")
    x, y, z = T[:3, 0], T[:3, 1], T[:3, 2]
    theta = np.radians(options.trocar_angle_deg)
    side = np.cos(azimuth_rad) * x + np.sin(azimuth_rad) * y
    return T[:3, 3] + depth * z + options.trocar_distance * (np.cos(theta) * -z + np.sin(theta) * side)


def instrument_poses(tips: np.ndarray, trocar: np.ndarray, view_dirs: np.ndarray, roll_rad: np.ndarray,
                     instrument: Instrument) -> np.ndarray:
    """T_world_instrument (F, 4, 4): +z from the trocar to the tip, +x (the hinge axis) along the view
    direction's part across the shaft turned by ``roll_rad``, the tip at ``tips``."""
    z = _unit(tips - trocar)
    x0 = view_dirs - np.sum(view_dirs * z, axis=1, keepdims=True) * z
    degenerate = np.linalg.norm(x0, axis=1) < 1e-9  # looking straight down the shaft
    x0[degenerate] = np.cross(z[degenerate], [0.0, 1.0, 0.0])
    x0 = _unit(x0)
    c, s = np.cos(roll_rad)[:, None], np.sin(roll_rad)[:, None]
    x = c * x0 + s * np.cross(z, x0)
    y = np.cross(z, x)
    T = np.tile(np.eye(4), (len(tips), 1, 1))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2] = x, y, z
    T[:, :3, 3] = tips - z * instrument.tip[2]
    return T


def _ring(axis: np.ndarray, radius: float) -> np.ndarray:
    """(RING_RAYS + 1, 3) offsets: the axis itself and a ring of ``radius`` around unit ``axis``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = _unit(np.cross(axis, helper))
    v = np.cross(axis, u)
    psi = 2.0 * np.pi * np.arange(RING_RAYS) / RING_RAYS
    return np.vstack([np.zeros(3), radius * (np.cos(psi)[:, None] * u + np.sin(psi)[:, None] * v)])


def clearance_along_parts(rc, poses: np.ndarray, jaw_angle: np.ndarray, trocar: np.ndarray,
                          instrument: Instrument, clearance: float) -> np.ndarray:
    """(F,) the smallest free length (metres) beyond the end of the shaft (cast from the trocar to the tip)
    and of each jaw (cast from the hinge to its end) on rays on and around their axes (radius: the part's
    plus ``clearance``); at least ``clearance`` means nothing comes closer to the tissue than that."""
    offsets = instrument.jaw_offsets(jaw_angle)
    tip_local = np.append(instrument.tip, 1.0)
    jaw_end = np.array([0.0, 0.0, float(instrument.jaw_length), 1.0])
    origins, directions, lengths = [], [], []
    for f, T in enumerate(poses):
        segments = [(trocar, (T @ tip_local)[:3], instrument.shaft_radius)]
        for offset in offsets.values():
            J = T @ offset[f]
            segments.append((J[:3, 3], (J @ jaw_end)[:3], 1.1 * instrument.jaw_radius))
        for start, end, radius in segments:
            axis = end - start
            length = float(np.linalg.norm(axis))
            axis /= length
            ring = _ring(axis, radius + clearance)
            origins.append(start + ring)
            directions.append(np.broadcast_to(axis, ring.shape))
            lengths.append(np.full(len(ring), length))
    t = rc.cast_rays(np.concatenate(origins), np.concatenate(directions))["t"]
    free = np.where(np.isfinite(t), t, np.inf) - np.concatenate(lengths)
    return free.reshape(len(poses), -1).min(axis=1)


def tip_in_view(rc, rig: StereoRig, path: CameraPath, tips: np.ndarray) -> np.ndarray:
    """(F,) bool: the tip projects inside both images, in front of the near clip, unhidden by the tissue."""
    out = np.ones(len(tips), bool)
    for f, tip in enumerate(tips):
        left = np.asarray(path.T_world_cam[f], dtype=np.float64)
        for T, camera in ((left, rig.left), (rig.right_pose(left), rig.right)):
            p = transform_points(invert_pose(T), tip)
            u, v = camera.project(p)
            inside = p[2] > rig.clip_start and bool(camera.in_image(u, v))
            hit = rc.cast_rays(T[:3, 3], tip - T[:3, 3])["t"]  # in units of the eye-to-tip distance
            out[f] &= bool(inside) and not (np.isfinite(hit) and hit < 1.0 - 1e-6)
    return out


def _eye_distance_ok(rig: StereoRig, path: CameraPath, tips: np.ndarray, trocar: np.ndarray,
                     instrument: Instrument) -> bool:
    """The shaft's axis (trocar to tip) passes at least shaft radius + EYE_DISTANCE from both eyes."""
    T = np.asarray(path.T_world_cam, dtype=np.float64)
    eyes = np.concatenate([T[:, :3, 3], np.stack([rig.right_pose(t)[:3, 3] for t in T])])
    a, b = np.concatenate([tips, tips]), trocar
    ab = b - a
    s = np.clip(np.sum((eyes - a) * ab, axis=1) / np.sum(ab * ab, axis=1), 0.0, 1.0)
    distance = np.linalg.norm(eyes - (a + s[:, None] * ab), axis=1)
    return bool(distance.min() >= instrument.shaft_radius + EYE_DISTANCE)


def _entry_offsets(rig: StereoRig, path: CameraPath, tips: np.ndarray, axes: np.ndarray, trocar: np.ndarray,
                   entry_frames: int, instrument: Instrument) -> np.ndarray:
    """(F,) how far back along the shaft the tip is: from outside both views at frame 0 to 0 at
    ``entry_frames`` (eased)."""
    out = np.zeros(len(tips))
    if entry_frames <= 0:
        return out
    left = np.asarray(path.T_world_cam[0], dtype=np.float64)
    reach = float(np.linalg.norm(tips[0] - trocar))
    start = reach
    for d in np.arange(0.0, reach, 0.001):
        p = tips[0] - d * axes[0]
        seen = False
        for T, camera in ((left, rig.left), (rig.right_pose(left), rig.right)):
            q = transform_points(invert_pose(T), p)
            u, v = camera.project(q)
            seen |= bool(q[2] > 0 and camera.in_image(u, v))
        if not seen:
            start = min(d + float(instrument.tip[2]), reach)  # the jaws and the wrist out of view too
            break
    f = np.arange(entry_frames)
    out[:entry_frames] = start * (0.5 + 0.5 * np.cos(np.pi * f / entry_frames))
    return out


def default_motion(rc, rig: StereoRig, path: CameraPath, instrument: Instrument,
                   options: MotionOptions | None = None, seed: int = 0,
                   extra_clearance: float = 0.0) -> InstrumentTrack:
    """The instrument's default motion over ``path`` above the tissue ray cast by ``rc`` (module docstring).

    ``extra_clearance`` (metres) is added to the options' clearance, e.g. the amplitude of a breathing
    surface. Raises ``ValueError`` when no trocar direction keeps the instrument clear of the tissue.
    """
    options = options or MotionOptions()
    seed = int(options.seed if options.seed is not None else seed)
    rng = np.random.default_rng(seed)
    frames, fps = path.frames, float(path.fps)
    intr = rig.intrinsics
    keys_seed = int(rng.integers(2**32))  # the same target keys for every trocar direction
    # from the left or the right (the wide sides of the image: more of the shaft in view), seeded
    azimuth0 = rng.choice([0.0, np.pi]) + rng.uniform(-1.0, 1.0) * np.radians(35.0)
    if options.trocar_azimuth_deg is not None:
        azimuth0 = np.radians(options.trocar_azimuth_deg)
    elif options.trocar is not None:  # where the given trocar lies in the middle frame's image
        middle = np.asarray(path.T_world_cam[frames // 2], dtype=np.float64)
        side = middle[:3, :3].T @ (np.asarray(options.trocar, dtype=np.float64) - middle[:3, 3])
        azimuth0 = float(np.arctan2(side[1], side[0]))
    t = np.arange(frames) / fps
    jaw = np.radians(options.jaw_open_deg) * 0.5 * (1.0 - np.cos(2 * np.pi * t / options.jaw_period_s
                                                                 + rng.uniform(0.0, 2.0 * np.pi)))
    roll_keys = rng.uniform(-1.0, 1.0, size=max(2, int(np.ceil(t[-1] / 2.0)) + 1)) if frames > 1 else np.zeros(2)
    roll = np.radians(options.roll_deg) * interpolate_keys(np.linspace(0.0, max(frames - 1, 1), len(roll_keys)),
                                                           roll_keys[:, None], np.arange(frames, dtype=float))[:, 0]
    view_dirs = np.asarray(path.T_world_cam, dtype=np.float64)[:, :3, 2]
    clearance = options.clearance + float(extra_clearance)
    entry_frames = int(round(options.entry_fraction * frames)) if frames > 1 else 0

    fixed = options.trocar is not None or options.trocar_azimuth_deg is not None
    tries = [azimuth0] if fixed else [azimuth0 + k * np.pi / 4 for k in (0, 1, -1, 2, -2, 3, -3, 4)]
    best, failures = None, []
    for azimuth in tries:
        trocar = trocar_point(rc, path, options, azimuth)
        # the tip drifts on the far side of the view from the trocar: the shaft crosses the image
        away = -TARGET_SHIFT * np.array([np.cos(azimuth), np.sin(azimuth)])
        uv = target_pixels(np.random.default_rng(keys_seed), frames,
                           fps, intr.width, intr.height, options.view_margin, options.drift_period_s, away)
        origins, directions = _pixel_rays_world(path, rig.left, uv)
        planned = _planned_depths(rc, origins, directions, options.hover)
        lift = np.zeros(frames)
        for _ in range(60):
            depths = planned - lift
            tips = origins + depths[:, None] * directions
            axes = _unit(tips - trocar)
            tips = tips - _entry_offsets(rig, path, tips, axes, trocar, entry_frames, instrument)[:, None] * axes
            poses = instrument_poses(tips, trocar, view_dirs, roll, instrument)
            free = clearance_along_parts(rc, poses, jaw, trocar, instrument, clearance)
            bad = free < clearance
            if not bad.any() or (depths < MIN_DEPTH_SHARE * planned).any():
                break
            lift = _smooth_lift(np.where(bad, lift + LIFT_STEP, lift))
        if bad.any():
            failures.append(f"azimuth {np.degrees(azimuth) % 360:.0f} deg: the tissue comes within "
                            f"{clearance * 1e3:.1f} mm of the instrument in {int(bad.sum())} frames")
            continue
        if not _eye_distance_ok(rig, path, tips, trocar, instrument):
            failures.append(f"azimuth {np.degrees(azimuth) % 360:.0f} deg: the shaft passes too close to the scope")
            continue
        in_view = tip_in_view(rc, rig, path, tips)
        settings = {"seed": seed, "options": options.to_dict(), "trocar_azimuth_deg": float(np.degrees(azimuth)),
                    "entry_frames": entry_frames, "clearance_m": clearance,
                    "lift_max_m": float(lift.max()), "in_view_fraction": float(in_view.mean()),
                    "clearance_min_m": float(free.min()), "target_pixels": uv.round(2).tolist()}
        track = InstrumentTrack(poses, jaw, tips, trocar, in_view, free, settings)
        if best is None or track.in_view_fraction > best.in_view_fraction:
            best = track
        if track.in_view_fraction >= 1.0 - options.entry_fraction - 0.1:
            break
    if best is None:
        raise ValueError("no trocar direction keeps the instrument clear of the tissue and the scope ("
                         + "; ".join(failures) + "); try a larger hover or trocar_distance")
    return best


def _smooth_lift(lift: np.ndarray) -> np.ndarray:
    """Lifts spread over neighbouring frames and smoothed, never lower than asked."""
    from scipy.ndimage import gaussian_filter1d, maximum_filter1d

    if len(lift) < 3:
        return lift
    return np.maximum(lift, gaussian_filter1d(maximum_filter1d(lift, 5, mode="nearest"), 1.0, mode="nearest"))
