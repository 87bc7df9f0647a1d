"""Path kinds drawn over the mesh: one generator function per kind, registered in ``PATH_GENERATORS``.

A generator is ``generator(ctx, rng, **options) -> Placement | None``: ``ctx`` (:class:`PathContext`) holds
the mesh surface, rig, timing and the current footprint allowance, ``rng`` a fresh seeded generator, and
the kind's own options are keyword-only parameters with defaults (``make_path`` rejects any other).
It checks its options (``ValueError`` via :func:`require`), draws the left-eye poses inside
``ctx.region(tilt)`` (return ``None`` when nothing fits: ``make_path`` then retries with a larger
allowance) and returns them with the settings that make it again (the resolved options, then what was
drawn).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rgbd2scene.scene.paths.surface import Surface, footprint_half, place, view_height
from rgbd2scene.scene.paths.track import look_at
from rgbd2scene.scene.paths.waypoints import interpolate_keys
from rgbd2scene.scene.rig import StereoRig


@dataclass(frozen=True)
class PathContext:
    """What a generator draws from: the mesh surface, the rig, the timing and one footprint allowance."""

    surface: Surface
    rig: StereoRig
    frames: int
    fps: float
    standoff: float  # metres from the left eye to the surface at the image centre
    speed: float  # m/s
    smooth: float  # Gaussian sigma (frames) of the standoff corrections
    relief: float  # both eyes' views stay on the mesh down to a depth of standoff * relief

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last (one frame's worth for a single frame)."""
        return max(self.frames - 1, 1) / self.fps

    @property
    def view_height(self) -> float:
        """Height (m) of the view at the standoff."""
        return view_height(self.rig, self.standoff)

    def region(self, tilt_deg: float) -> np.ndarray:
        """Surface cells (``surface.valid``'s grid) the camera can be over, tilted up to ``tilt_deg`` from +z."""
        return self.surface.region(*footprint_half(self.rig, self.standoff * self.relief, np.radians(tilt_deg)))


class Placement(NamedTuple):
    """A generator's result: left-eye poses T_world_cam (F, 4, 4) and the settings that make them again."""

    poses: np.ndarray
    settings: dict


def require(*checks: tuple[bool, str]) -> None:
    """Raise ``ValueError`` with the message of the first ``(ok, message)`` check that fails."""
    for ok, message in checks:
        if not ok:
            raise ValueError(message)


def _rotations(yaw, pitch, roll) -> np.ndarray:
    """Camera orientations (F, 3, 3): the capture orientation turned by small yaw/pitch/roll (radians)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("YXZ", np.stack([yaw, pitch, roll], axis=-1)).as_matrix()


def _smooth_noise(rng, n: int, frames: int, amplitude: float) -> np.ndarray:
    """Smooth random signal in [-amplitude, amplitude] through n random keys spread over the frames."""
    if amplitude <= 0:
        return np.zeros(frames)
    keys = rng.uniform(-amplitude, amplitude, size=max(n, 2))
    if frames == 1:
        return keys[:1]
    return np.clip(interpolate_keys(np.linspace(0, frames - 1, len(keys)), keys[:, None],
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
        ground = interpolate_keys(times, np.array(pts), t)
        if surface.inside(region, ground).all():
            return ground
    return None


def static_path(ctx: PathContext, rng: np.random.Generator) -> Placement | None:
    """One pose over the most interior point of the surface, looking along +z."""
    region = ctx.region(0.0)
    if not region.any():
        return None
    centre = ctx.surface.most_interior(region)
    zeros = np.zeros(ctx.frames)
    T = place(ctx.surface, np.tile(centre, (ctx.frames, 1)), _rotations(zeros, zeros, zeros), ctx.standoff, 0.0)
    return Placement(T, {"centre": centre.tolist()})


def scan_path(ctx: PathContext, rng: np.random.Generator, *, length=None, rows=1, row_spacing=None, angle=None,
              tilt=0.0) -> Placement | None:
    """A sweep with smooth start and stop.

    ``length`` metres (default speed x duration, shortened when it does not fit), ``rows`` parallel rows
    ``row_spacing`` metres apart (default half the view height) walked as a serpentine, at ``angle``
    degrees from +x (seeded random by default), the view tilted ``tilt`` degrees forward along the sweep.
    """
    tilt, rows = float(tilt), int(rows)
    require((0.0 <= tilt < 60.0, f"tilt must lie in [0, 60) degrees, got {tilt}"),
            (rows >= 1, f"rows must be at least 1, got {rows}"),
            (length is None or float(length) > 0, f"length must be positive, got {length}"))
    length = float(length) if length is not None else ctx.speed * ctx.duration
    row_spacing = float(row_spacing) if row_spacing is not None else 0.5 * ctx.view_height
    region = ctx.region(tilt)
    if not region.any():
        return None
    a = None if angle is None else np.radians(float(angle))
    sweep = _scan_ground(ctx.surface, region, rng, ctx.frames, length, rows, row_spacing, a)
    if sweep is None:
        return None
    ground, a, used_length = sweep
    th, F = np.radians(tilt), ctx.frames
    R = _rotations(np.full(F, th * np.cos(a)), np.full(F, -th * np.sin(a)), np.zeros(F))
    T = place(ctx.surface, ground, R, ctx.standoff, ctx.smooth)
    return Placement(T, {"length": float(used_length), "rows": rows, "row_spacing": row_spacing, "tilt": tilt,
                         "angle": float(np.degrees(a))})


def orbit_path(ctx: PathContext, rng: np.random.Generator, *, tilt=20.0, turns=1.0) -> Placement | None:
    """Circles the most interior point ``turns`` times (from a seeded phase), looking at it ``tilt`` degrees
    off +z."""
    tilt, turns = float(tilt), float(turns)
    require((0.0 <= tilt < 60.0, f"tilt must lie in [0, 60) degrees, got {tilt}"),
            (np.isfinite(turns), f"turns must be a number, got {turns}"))
    region = ctx.region(tilt)
    if not region.any():
        return None
    centre = ctx.surface.most_interior(region)
    target = np.array([*centre, ctx.surface.height_at(centre[None])[0]])
    F = ctx.frames
    phase = rng.uniform(0.0, 2.0 * np.pi)
    phi = phase + 2.0 * np.pi * turns * np.arange(F) / max(F, 1)
    th = np.radians(tilt)
    pos = target + ctx.standoff * np.column_stack(
        [np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), -np.full(F, np.cos(th))])
    R = np.stack([look_at(p, target)[:3, :3] for p in pos])
    T = place(ctx.surface, None, R, ctx.standoff, ctx.smooth, target=np.tile(target, (F, 1)))
    return Placement(T, {"tilt": tilt, "turns": turns, "centre": target.tolist(), "phase": float(phase)})


def random_path(ctx: PathContext, rng: np.random.Generator, *, max_tilt=12.0, max_roll=10.0) -> Placement | None:
    """A seeded smooth wander at the context's speed, the view tilted up to ``max_tilt`` degrees from +z and
    rolled up to ``max_roll`` degrees, both varying smoothly."""
    max_tilt, max_roll = float(max_tilt), float(max_roll)
    require((0.0 <= max_tilt < 60.0, f"max_tilt must lie in [0, 60) degrees, got {max_tilt}"),
            (0.0 <= max_roll <= 180.0, f"max_roll must lie in [0, 180] degrees, got {max_roll}"))
    region = ctx.region(max_tilt)
    if not region.any():
        return None
    F = ctx.frames
    ground = _random_ground(ctx.surface, region, rng, F, ctx.fps, ctx.speed)
    if ground is None:
        return None
    n_keys = int(np.clip(np.ceil(ctx.duration / 1.0), 1, 30)) + 1
    yaw = _smooth_noise(rng, n_keys, F, np.radians(max_tilt) / np.sqrt(2))
    pitch = _smooth_noise(rng, n_keys, F, np.radians(max_tilt) / np.sqrt(2))
    roll = _smooth_noise(rng, n_keys, F, np.radians(max_roll))
    T = place(ctx.surface, ground, _rotations(yaw, pitch, roll), ctx.standoff, ctx.smooth)
    return Placement(T, {"speed": ctx.speed, "max_tilt": max_tilt, "max_roll": max_roll})


#: Path kinds drawn over the mesh, by name (the CLI's ``--path`` choices, in this order).
PATH_GENERATORS = {
    "static": static_path,
    "scan": scan_path,
    "orbit": orbit_path,
    "random": random_path,
}
