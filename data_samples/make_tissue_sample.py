#!/usr/bin/env python3
"""Generate the bundled synthetic Kinect-style RGB-D capture of ex-vivo tissue (deterministic, seeded).

Usage: ``python data_samples/make_tissue_sample.py data_samples/tissue [--seed N]``

The scene is a liver-like organ (four smooth, bulging lobes with fissures and folds) lying on a blue
surgical drape, seen obliquely from about 0.6 m by a PrimeSense/Kinect v1 (640x480, fx=fy=525,
cx=319.5, cy=239.5). Geometry is a 1 mm height field ray-cast with Open3D; the sensor model is:

- depth from an IR camera 2.5 cm to the left of the RGB camera, registered to the RGB pixel grid
  (pure x translation, so planar z is shared); pixels the IR camera cannot see are holes;
- structured-light occlusion shadows: the IR projector sits 7.5 cm to the right (+x) of the IR camera;
  surface points it cannot light are holes (they lie on the far surface, left of depth steps);
- disparity-domain noise and quantisation: Kinect raw codes are 1/8-pixel disparity steps with
  z = 351.3 / (1092.5 - raw) (the NYU toolbox calibration, about 2.85e-3 z^2 m per code);
  noise sigma_d = 0.5 code (Khoshelham & Elberink 2012: sigma_z = 1.42e-3 z^2) plus the
  angle-dependent term of Nguyen, Izadi & Lovell (2012), spatially correlated over a few pixels
  like the sensor's correlation window; depth is then stored in whole millimetres (OpenNI);
- dropouts at grazing angles and beside depth discontinuities, sparse speckle holes;
- specular highlights on the wet organ (saturated white in RGB) are holes in depth as well;
- the invalid band of a registered Kinect depth image along the left and top borders.

Outputs (all written atomically): rgb.png, depth.png (uint16 mm), camera.json (with depth_scale),
depth_gt.npy (float32 metres, noise-free, no holes), hole_cause.png (uint8 codes, see HOLE_CAUSES)
and README.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage

try:
    from rgbd2scene.files import atomic
except ImportError:  # run from a checkout without the package installed
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from rgbd2scene.files import atomic

W, H = 640, 480
FX = FY = 525.0
CX, CY = (W - 1) / 2.0, (H - 1) / 2.0
DEPTH_SCALE = 1000.0  # uint16 millimetres, as OpenNI delivers them
SEED = 20240611
GRID = 0.001  # height-field and texture spacing, metres
GEOM_STEP = 2  # the ray-cast mesh takes every 2nd height sample (2 mm triangles)

# Kinect v1 geometry and disparity model.
IR_OFFSET_X = -0.025  # IR camera relative to the RGB camera, along the camera x axis (m)
PROJECTOR_BASELINE = 0.075  # projector relative to the IR camera, +x (m)
KINECT_FB = 351.3  # z = KINECT_FB / (KINECT_OFFSET - raw): 1/8-pixel disparity codes (NYU calibration)
KINECT_OFFSET = 1092.5
SIGMA_D_CODES = 0.5  # Khoshelham & Elberink 2012: sigma_d = 1/2 code -> sigma_z = 1.42e-3 z^2
MIN_RANGE = 0.45  # Kinect v1 returns nothing nearer than this (m)

# appearance and shape
SHININESS, SPEC_SHARP = 220.0, 2.5  # wet capsule: sharp, strong highlights
EXPOSURE = 1.3
RIM_CLIFF = 0.4  # fraction of a lobe's height that stands as a near-vertical side at its rim

HOLE_CAUSES = {
    0: "valid",
    1: "invalid border band (registration)",
    2: "projector shadow (structured-light occlusion)",
    3: "not visible from the IR camera",
    4: "specular highlight (saturated)",
    5: "grazing angle / depth-discontinuity dropout",
    6: "speckle dropout",
}


# --------------------------------------------------------------------------------------------------
# procedural noise


def fbm(shape, rng, beta=2.0, fmin=1.0, fmax=None, down=1):
    """Zero-mean, unit-std fractal noise with a 1/f^beta power spectrum in a band (cycles per image).

    ``down`` > 1 synthesises on a coarser grid and upsamples (for fields without fine detail).
    """
    h, w = shape
    gh, gw = -(-h // down), -(-w // down)
    white = rng.standard_normal((gh, gw))
    fy = np.fft.fftfreq(gh)[:, None] * gh
    fx = np.fft.rfftfreq(gw)[None, :] * gw
    f = np.hypot(fx * (max(gh, gw) / gw), fy * (max(gh, gw) / gh))
    amp = np.zeros_like(f)
    band = f >= fmin
    if fmax is not None:
        band &= f <= fmax
    amp[band] = f[band] ** (-beta / 2.0)
    out = sp_fft.irfft2(sp_fft.rfft2(white) * amp, s=(gh, gw))
    if down > 1:
        out = cv2.resize(out, (w, h), interpolation=cv2.INTER_CUBIC)
    out -= out.mean()
    return out / (out.std() + 1e-12)


# --------------------------------------------------------------------------------------------------
# scene: height field in a world frame (x right, y away from the camera, z up; metres)


def camera_pose():
    """Rotation (columns = camera x, y, z axes in world) and centre of the RGB camera."""
    centre = np.array([0.0, -0.20, 0.64])
    target = np.array([0.0, 0.04, 0.0])
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    # a few degrees of roll, as a hand-placed tripod would have
    y = np.cross(z, x)
    roll = np.deg2rad(-3.0)
    x, y = np.cos(roll) * x + np.sin(roll) * y, -np.sin(roll) * x + np.cos(roll) * y
    return np.stack([x, y, z], axis=1), centre


def pixel_dirs(R, width, height, fx, fy, cx, cy):
    """World-frame ray directions with unit camera-z component (so t_hit = planar depth)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    d = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)
    return d @ R.T


def build_heightfield(rng, x0, y0, nx, ny):
    """Drape plus organ height (m) on the grid, the organ's own height, and the material fields."""
    xs = x0 + GRID * np.arange(nx)
    ys = y0 + GRID * np.arange(ny)
    X, Y = np.meshgrid(xs, ys)

    # drape: a few soft folds and gentle undulation (0..~15 mm)
    drape = np.full(X.shape, 0.004)
    for cx_, cy_, ang, amp, width in [(-0.36, 0.05, 70, 0.009, 0.035), (0.40, -0.05, 100, 0.011, 0.04),
                                      (0.05, 0.38, 10, 0.008, 0.03), (-0.25, -0.22, 150, 0.006, 0.025),
                                      (0.30, 0.30, 40, 0.007, 0.03)]:
        a = np.deg2rad(ang)
        dist = -(X - cx_) * np.sin(a) + (Y - cy_) * np.cos(a)
        along = (X - cx_) * np.cos(a) + (Y - cy_) * np.sin(a)
        drape += amp * np.exp(-(dist / width) ** 2) * np.exp(-(along / 0.25) ** 2)
    drape += 0.0025 * fbm(X.shape, rng, beta=3.5, fmin=2.0, fmax=80, down=2)
    drape = np.clip(drape, 0.0, None)

    # organ: four bulging lobes, smooth-max blended (fissures become creases)
    warp = fbm(X.shape, rng, beta=3.5, fmin=1.5)
    organ = np.zeros_like(X)
    lobes = [  # cx, cy, a, b, angle, height, tilt
        (0.13, 0.07, 0.225, 0.165, 18, 0.070, -0.15),
        (-0.17, 0.04, 0.19, 0.145, -25, 0.046, -0.30),
        (-0.02, -0.11, 0.14, 0.085, 8, 0.036, 0.2),
        (0.00, 0.23, 0.21, 0.10, -5, 0.042, 0.1),
    ]
    for cx_, cy_, a, b, ang, height, tilt in lobes:
        t = np.deg2rad(ang)
        xr = (X - cx_) * np.cos(t) + (Y - cy_) * np.sin(t)
        yr = -(X - cx_) * np.sin(t) + (Y - cy_) * np.cos(t)
        r = np.sqrt((xr / a) ** 2 + (yr / b) ** 2) + 0.07 * warp
        dome = np.sqrt(np.clip(1.0 - r**2, 0.0, None))
        rim = np.clip((1.0 - r) / 0.03, 0.0, 1.0)  # the side drops steeply over the last ~4 mm
        lobe = height * rim * rim * (3 - 2 * rim) * (RIM_CLIFF + (1 - RIM_CLIFF) * dome)
        lobe *= np.clip(1.0 + tilt * xr / a, 0.3, None)
        # where two lobes meet at a similar height a fissure runs between them; elsewhere the
        # higher lobe's rim stands as a step over the lower one
        both = (organ > 0) & (lobe > 0)
        fissure = np.where(both, np.exp(-((organ - lobe) / 0.006) ** 2), 0.0)
        organ = np.maximum(organ, lobe) - 0.007 * fissure
    organ = ndimage.gaussian_filter(organ, 1.0)  # round the fissures' V a little
    organ[organ < 2e-4] = 0.0
    inside = organ > 0.0

    # folds and grooves on the capsule (a few mm), low-frequency bumps
    grooves = np.zeros(X.shape, np.float32)
    for _ in range(9):
        p = np.array([rng.uniform(-0.25, 0.25), rng.uniform(-0.12, 0.25)])
        ang = rng.uniform(0, np.pi)
        pts = []
        for _s in range(8):
            pts.append(p.copy())
            ang += rng.normal(0, 0.35)
            p = p + 0.018 * np.array([np.cos(ang), np.sin(ang)])
        pix = np.round((np.array(pts) - [x0, y0]) / GRID).astype(np.int32)
        cv2.polylines(grooves, [pix], False, float(rng.uniform(0.5, 1.0)), thickness=3, lineType=cv2.LINE_AA)
    grooves = ndimage.gaussian_filter(grooves, 3.0)
    grooves /= grooves.max() + 1e-9
    organ_w = np.clip(organ / 0.01, 0.0, 1.0)  # fade details out at the rim
    detail = -0.0035 * grooves + 0.0020 * fbm(X.shape, rng, beta=3.5, fmin=4.0, fmax=60, down=2)
    organ = np.where(inside, np.clip(organ + organ_w * detail, 0.0, None), 0.0)
    height = drape + organ
    return xs, ys, height, organ, inside


def heightfield_mesh(xs, ys, height):
    X, Y = np.meshgrid(xs, ys)
    verts = np.stack([X, Y, height], axis=-1).reshape(-1, 3).astype(np.float32)
    ny, nx = height.shape
    idx = np.arange(ny * nx, dtype=np.int32).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    return verts, tris


class Caster:
    def __init__(self, verts, tris):
        import open3d as o3d

        self.o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(tris.astype(np.uint32)))

    def t_hit(self, origins, dirs):
        o = np.broadcast_to(origins, dirs.shape).reshape(-1, 3)
        rays = np.concatenate([o, dirs.reshape(-1, 3)], axis=1).astype(np.float32)
        ans = self.scene.cast_rays(self.o3d.core.Tensor(rays))
        return ans["t_hit"].numpy().reshape(dirs.shape[:-1]).astype(np.float64)

    def visible_from(self, point, targets):
        """True where the straight segment from ``point`` to each target is unobstructed."""
        t = self.t_hit(point, targets - point)
        return t > 1.0 - 2e-3


# --------------------------------------------------------------------------------------------------
# appearance


def vessel_map(rng, shape, inside):
    """Branching surface vessels: (darkness 0..1, redness 0..1) on the texture grid."""
    dark = np.zeros(shape, np.float32)
    red = np.zeros(shape, np.float32)
    ny, nx = shape
    inside_px = np.argwhere(ndimage.binary_erosion(inside, iterations=15))
    stack = []
    for _ in range(26):
        r, c = inside_px[rng.integers(len(inside_px))]
        stack.append((np.array([c, r], np.float64), rng.uniform(0, 2 * np.pi), rng.uniform(2.5, 4.5), 0,
                      bool(rng.random() < 0.35)))
    while stack:
        p, ang, width, depth, artery = stack.pop()
        n_seg = int(rng.integers(4, 9))
        for _ in range(n_seg):
            ang += rng.normal(0, 0.28)
            step = rng.uniform(4.0, 8.0)
            q = p + step * np.array([np.cos(ang), np.sin(ang)])
            if not (0 <= q[0] < nx and 0 <= q[1] < ny) or not inside[int(q[1]), int(q[0])]:
                break
            target = red if artery else dark
            thick = max(1, int(round(width)))
            cv2.line(target, tuple(np.round(p * 4).astype(int)), tuple(np.round(q * 4).astype(int)),
                     float(min(1.0, 0.35 + 0.25 * width)), thickness=thick, lineType=cv2.LINE_AA, shift=2)
            p = q
            width *= 0.93
            if width > 0.9 and depth < 5 and rng.random() < 0.28:
                stack.append((p.copy(), ang + rng.choice([-1, 1]) * rng.uniform(0.35, 0.8), width * 0.75,
                              depth + 1, artery))
    dark = ndimage.gaussian_filter(dark, 1.1)
    red = ndimage.gaussian_filter(red, 1.1)
    return np.clip(dark, 0, 1), np.clip(red, 0, 1)


def albedo_maps(rng, xs, ys, organ, inside):
    """Linear-RGB albedo, specular strength and micro-bump field on the 1 mm texture grid."""
    shape = organ.shape
    srgb2lin = lambda c: np.asarray(c, np.float64) ** 2.2  # noqa: E731

    # tissue: reddish-pink to deep red-brown, mottled, with vessels and pale patches of fat/fascia
    low = fbm(shape, rng, beta=3.0, fmin=2.0, fmax=40)
    mid = fbm(shape, rng, beta=2.0, fmin=10, fmax=150)
    fine = fbm(shape, rng, beta=0.5, fmin=150)
    mix = np.clip(0.5 + 0.28 * low, 0.0, 1.0)[..., None]
    c_pink, c_brown = srgb2lin([0.72, 0.33, 0.33]), srgb2lin([0.48, 0.14, 0.12])
    tissue = c_pink * (1 - mix) + c_brown * mix
    tissue *= (1.0 + 0.09 * mid + 0.025 * fine)[..., None]
    fat = np.clip((fbm(shape, rng, beta=3.0, fmin=3.0, down=4) - 1.8) * 1.2, 0, 1)[..., None] * 0.35
    tissue = tissue * (1 - fat) + srgb2lin([0.80, 0.62, 0.45]) * fat
    dark, red = vessel_map(rng, shape, inside)
    tissue = tissue * (1 - 0.7 * dark[..., None]) + srgb2lin([0.36, 0.08, 0.22]) * 0.7 * dark[..., None]
    tissue = tissue * (1 - 0.7 * red[..., None]) + srgb2lin([0.66, 0.05, 0.06]) * 0.7 * red[..., None]
    # thin rim: the lobe edges look darker and more translucent
    rim = np.clip(1.0 - organ / 0.012, 0.0, 1.0)[..., None]
    tissue *= 1.0 - 0.35 * rim

    # drape: blue surgical cloth with a fabric grain, some blood and fluid stains
    grain = fbm(shape, rng, beta=0.3, fmin=200)
    weave = 1.0 + 0.06 * fbm(shape, rng, beta=2.5, fmin=2) + 0.07 * grain
    cloth = srgb2lin([0.16, 0.34, 0.52]) * weave[..., None]
    stain_field = fbm(shape, rng, beta=2.8, fmin=4.0)
    dist_organ = ndimage.distance_transform_edt(~inside) * GRID
    stain = np.clip((stain_field - 0.8) * 2.0, 0, 1) * np.exp(-dist_organ / 0.05)
    cloth = cloth * (1 - stain[..., None]) + srgb2lin([0.22, 0.05, 0.07]) * stain[..., None]

    w = np.clip(organ / 0.0015, 0.0, 1.0)[..., None]
    albedo = tissue * w + cloth * (1 - w)
    spec = np.where(inside, 1.0, 0.01 + 0.4 * stain)
    bumps = 0.0003 * fbm(shape, rng, beta=3.0, fmin=8, fmax=120) * w[..., 0]
    return albedo.astype(np.float32), spec.astype(np.float32), bumps.astype(np.float32)


def sample_grid(field, xs, ys, pts):
    """Bilinear lookup of a grid field (ny, nx[, c]) at world points (..., 3)."""
    cols = (pts[..., 0] - xs[0]) / GRID
    rows = (pts[..., 1] - ys[0]) / GRID
    coords = np.stack([rows.ravel(), cols.ravel()])
    if field.ndim == 2:
        return ndimage.map_coordinates(field, coords, order=1, mode="nearest").reshape(pts.shape[:-1])
    chans = [ndimage.map_coordinates(field[..., k], coords, order=1, mode="nearest")
             for k in range(field.shape[2])]
    return np.stack(chans, -1).reshape(pts.shape[:-1] + (field.shape[2],))


def normals_at(grad, xs, ys, pts):
    gx, gy = sample_grid(grad[0], xs, ys, pts), sample_grid(grad[1], xs, ys, pts)
    n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# --------------------------------------------------------------------------------------------------


def make_sample(out_dir, seed: int = SEED, verbose: bool = True) -> dict:
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    rng = np.random.default_rng(seed)
    R, C = camera_pose()
    dirs = pixel_dirs(R, W, H, FX, FY, CX, CY)

    # grid bounds: footprint of the image on the ground plane plus a margin
    t_ground = -C[2] / dirs[..., 2]
    foot = C + dirs * t_ground[..., None]
    x0, x1 = foot[..., 0].min() - 0.06, foot[..., 0].max() + 0.06
    y0, y1 = foot[..., 1].min() - 0.06, foot[..., 1].max() + 0.06
    nx, ny = int(np.ceil((x1 - x0) / GRID)) + 1, int(np.ceil((y1 - y0) / GRID)) + 1
    xs, ys, height, organ, inside = build_heightfield(rng, x0, y0, nx, ny)
    albedo, spec_map, bumps = albedo_maps(rng, xs, ys, organ, inside)
    caster = Caster(*heightfield_mesh(xs[::GEOM_STEP], ys[::GEOM_STEP], height[::GEOM_STEP, ::GEOM_STEP]))
    grad = np.gradient(height, GRID)[::-1]  # (d/dx, d/dy)
    grad_micro = np.gradient(height + bumps, GRID)[::-1]

    # ---- exact depth at the pixel centres
    depth_gt = caster.t_hit(C, dirs)
    if not np.isfinite(depth_gt).all():
        raise RuntimeError("some pixel rays miss the scene; enlarge the height field")
    pts = C + dirs * depth_gt[..., None]

    # ---- RGB: 2x2 supersampled shading; a lamp slightly above and right of the sensor
    lamp = C + R @ np.array([0.18, -0.22, 0.0])
    n = normals_at(grad, xs, ys, pts)
    lit = caster.visible_from(lamp, pts + 1e-4 * n).astype(np.float32)
    lit = cv2.GaussianBlur(lit, (0, 0), 1.0)  # soft shadow edge of an extended lamp
    ss = 2
    dirs2 = pixel_dirs(R, W * ss, H * ss, FX * ss, FY * ss, (CX + 0.5) * ss - 0.5, (CY + 0.5) * ss - 0.5)
    p2 = C + dirs2 * caster.t_hit(C, dirs2)[..., None]
    lit2 = cv2.resize(lit, (W * ss, H * ss), interpolation=cv2.INTER_LINEAR).astype(np.float64)
    nm2 = normals_at(grad_micro, xs, ys, p2)
    to_l = unit(lamp - p2)
    fall = (0.75 / np.linalg.norm(lamp - p2, axis=-1)) ** 2
    diffuse = np.clip(np.sum(nm2 * to_l, -1), 0, None) * lit2 * fall
    ndh = np.clip(np.sum(nm2 * unit(to_l + unit(C - p2)), -1), 0, None)
    ks = sample_grid(spec_map, xs, ys, p2)
    specular = ks * (SPEC_SHARP * ndh**SHININESS + 0.05 * ndh**40) * lit2 * fall
    alb = sample_grid(albedo, xs, ys, p2)
    lin = alb * (0.20 + 1.0 * diffuse)[..., None] + specular[..., None] * np.array([1.0, 0.97, 0.94])
    lin = cv2.resize(lin.astype(np.float32), (W, H), interpolation=cv2.INTER_AREA).astype(np.float64)
    v, u = np.mgrid[0:H, 0:W]
    vignette = 1.0 - 0.6 * (((u - CX) / W) ** 2 + ((v - CY) / H) ** 2)
    lin *= EXPOSURE * vignette[..., None]
    srgb = np.clip(lin, 0, 1) ** (1 / 2.2)
    srgb = cv2.GaussianBlur(srgb.astype(np.float32), (0, 0), 0.6).astype(np.float64)  # Bayer/lens softness
    noise = rng.standard_normal((H, W, 1)) * 0.007 + rng.standard_normal((H, W, 3)) * 0.004
    srgb = srgb + noise * np.sqrt(np.clip(srgb, 0.02, 1))
    rgb = np.clip(np.round(srgb * 255), 0, 255).astype(np.uint8)
    saturated = rgb.min(axis=2) >= 248

    # ---- depth sensor
    cause = np.zeros((H, W), np.uint8)
    ir_cam = C + R[:, 0] * IR_OFFSET_X
    projector = ir_cam + R[:, 0] * PROJECTOR_BASELINE
    nm = normals_at(grad_micro, xs, ys, pts)
    lift = pts + 1e-4 * n
    seen_ir = caster.visible_from(ir_cam, lift)
    lit_proj = caster.visible_from(projector, lift)

    # noise-free disparity code, then noise (sigma_d = 0.5 code, plus Nguyen's angle term)
    z = depth_gt
    cos_ir = np.clip(np.sum(n * unit(ir_cam - pts), -1), 1e-3, 1.0)
    theta = np.arccos(cos_ir)
    sigma_angle_m = 1e-4 / np.sqrt(z) * theta**2 / np.clip(np.pi / 2 - theta, 0.05, None) ** 2
    sigma_codes = np.hypot(SIGMA_D_CODES, sigma_angle_m * KINECT_FB / z**2)
    corr = ndimage.gaussian_filter(rng.standard_normal((H, W)), 1.5)
    corr /= corr.std()
    white = rng.standard_normal((H, W))
    code = KINECT_OFFSET - KINECT_FB / z + sigma_codes * (0.8 * corr + 0.6 * white)
    raw = np.round(code)
    z_meas = KINECT_FB / (KINECT_OFFSET - raw)

    # grazing-angle and discontinuity dropouts (probabilistic edges)
    speck = rng.random((H, W))
    grazing = (cos_ir < 0.20) | ((cos_ir < 0.35) & (speck < (0.35 - cos_ir) / 0.15 * 0.6))
    zpad = np.pad(z, 1, mode="edge")
    jump = np.zeros_like(z)
    for dv, du in ((0, 1), (1, 0), (2, 1), (1, 2)):
        jump = np.maximum(jump, np.abs(zpad[dv:dv + H, du:du + W] - z) / z)
    edge = jump > 0.02
    edge_zone = ndimage.binary_dilation(edge, iterations=2)
    dropout = grazing | (edge_zone & (speck < 0.35)) | edge & (speck < 0.75)

    # shadow boundaries are ragged on a real sensor: grow them by 0-2 px, randomly
    shadow = ~lit_proj
    grow = ndimage.binary_dilation(shadow, iterations=1) & (rng.random((H, W)) < 0.55)
    shadow = ndimage.binary_opening(shadow | grow, iterations=1) | shadow

    # specular: IR saturation where the projector's mirror reflection enters the IR camera, and
    # the saturated RGB highlights (the lamp sits next to the sensor, so they nearly coincide)
    ks = sample_grid(spec_map, xs, ys, pts)
    half_ir = unit(unit(projector - pts) + unit(ir_cam - pts))
    spec_ir = ks * SPEC_SHARP * np.clip(np.sum(nm * half_ir, -1), 0, None) ** SHININESS
    specular_hole = ndimage.binary_dilation((spec_ir > 1.0) | saturated, iterations=1)

    # sparse speckle holes (low IR return on dark, wet patches)
    blobs = ndimage.gaussian_filter(rng.standard_normal((H, W)), 1.2)
    speckle = blobs > 3.1 * blobs.std()

    # registration band: left ~8 px and top ~3 px, ragged at its inner edge
    v_i, u_i = np.mgrid[0:H, 0:W]
    jitter = rng.integers(0, 3, size=(H, 1))
    border = (u_i < 7 + jitter) | (v_i < 2 + rng.integers(0, 2, size=(1, W)))

    for code_id, mask in ((6, speckle), (5, dropout), (4, specular_hole), (3, ~seen_ir), (2, shadow),
                          (1, border)):
        cause[mask] = code_id
    cause[z_meas < MIN_RANGE] = 5
    depth_mm = np.round(z_meas * DEPTH_SCALE)
    depth_mm[cause > 0] = 0
    depth_png = np.clip(depth_mm, 0, 65535).astype(np.uint16)

    # ---- write
    out_dir.mkdir(parents=True, exist_ok=True)
    bgr = np.ascontiguousarray(rgb[..., ::-1])
    # zlib levels: 9 is slow on the noisy 16-bit depth for a few % gain, so it gets 6
    for name, img, level in (("rgb.png", bgr, 9), ("depth.png", depth_png, 6), ("hole_cause.png", cause, 9)):
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, level])
        if not ok:
            raise RuntimeError(f"PNG encoding failed for {name}")
        atomic.write_bytes(out_dir / name, buf.tobytes())
    atomic.write_npy(out_dir / "depth_gt.npy", depth_gt.astype(np.float32))
    camera = {"width": W, "height": H, "fx": FX, "fy": FY, "cx": CX, "cy": CY, "depth_scale": DEPTH_SCALE}
    atomic.write_text(out_dir / "camera.json", json.dumps(camera, indent=2) + "\n")

    valid = depth_png > 0
    err = (depth_png[valid] / DEPTH_SCALE - depth_gt[valid]) * 1000.0
    stats = {
        "seed": seed,
        "hole_fraction": float(1.0 - valid.mean()),
        "hole_fraction_by_cause": {HOLE_CAUSES[k]: float((cause == k).mean()) for k in range(1, 7)},
        "depth_gt_range_m": [float(depth_gt.min()), float(depth_gt.max())],
        "organ_fraction": float(sample_grid(inside.astype(np.float32), xs, ys, pts).__gt__(0.5).mean()),
        "sensor_error_mm": {"mean": float(err.mean()), "rms": float(np.sqrt(np.mean(err**2))),
                            "p99_abs": float(np.percentile(np.abs(err), 99))},
        "saturated_rgb_fraction": float(saturated.mean()),
        "seconds": time.perf_counter() - t0,
    }
    atomic.write_text(out_dir / "README.md", readme_text(stats))
    if verbose:
        print(json.dumps(stats, indent=2))
    return stats


def readme_text(stats: dict) -> str:
    causes = "\n".join(f"| {k} | {v} | {100 * stats['hole_fraction_by_cause'].get(v, 0.0):.2f} % |"
                       for k, v in HOLE_CAUSES.items() if k)
    lo, hi = stats["depth_gt_range_m"]
    err = stats["sensor_error_mm"]
    return f"""# Bundled sample: synthetic Kinect v1 capture of ex-vivo tissue

Generated by `python data_samples/make_tissue_sample.py data_samples/tissue` (seed {stats['seed']},
deterministic: the same seed writes byte-identical files with the pinned numpy/scipy/OpenCV/Open3D).
Synthetic and generated here, so it has exact ground truth and no third-party data in it.

A liver-like organ (four bulging lobes with fissures, folds, surface vessels, mottling and pale
patches) lies on a blue surgical drape with a few folds and blood stains, seen obliquely (about
20 degrees from straight down, 0.64 m above the drape) by a PrimeSense / Kinect v1 in an ex-vivo
lab setting. The organ covers {100 * stats['organ_fraction']:.0f} % of the image and stands
4-7 cm high; every pixel sees a surface (organ or drape), depth {lo:.3f}-{hi:.3f} m (one pixel is
about 1.1 mm there). The scene is a 1 mm height field (ray-cast as a 2 mm triangle mesh); RGB is
rendered 2x2 supersampled with a lamp above and right of the sensor, wet specular highlights, a
slight blur, vignetting and sensor noise.

| file | content |
|---|---|
| `rgb.png` | 640x480 8-bit sRGB, registered to the depth |
| `depth.png` | 640x480 uint16 depth in millimetres (`depth_scale` 1000 units per metre); 0 = hole |
| `camera.json` | `width, height, fx, fy, cx, cy, depth_scale`: 525, 525, 319.5, 239.5 (PrimeSense default) |
| `depth_gt.npy` | float32 planar depth in metres, noise-free, no holes (exact surface at each pixel centre) |
| `hole_cause.png` | uint8 code of why each depth pixel is missing (table below), 0 = valid |

Load it with
`rgbd2scene.capture.load_capture(rgb, depth, intr, scale)` where
`intr, scale = rgbd2scene.capture.camera.load_camera_json("data_samples/tissue/camera.json")`.

## Sensor model

- **Quantisation:** depth is measured as Kinect raw disparity codes (1/8-pixel steps),
  z = 351.3 / (1092.5 - raw) m (the NYU Depth toolbox calibration); one code is about
  2.85e-3 z^2 m (1.0 mm at 0.6 m, 1.5 mm at 0.73 m). The result is stored in whole millimetres,
  as OpenNI delivers it.
- **Noise:** sigma_d = 0.5 code in disparity (Khoshelham & Elberink 2012: sigma_z = 1.42e-3 z^2 m),
  plus the incidence-angle term of Nguyen, Izadi & Lovell 2012, spatially correlated over a few
  pixels like the sensor's correlation window. Sensor minus ground truth over valid pixels:
  mean {err['mean']:+.2f} mm, RMS {err['rms']:.2f} mm, 99th percentile |error| {err['p99_abs']:.2f} mm.
- **Occlusion shadows:** the IR camera sits 2.5 cm left of the RGB camera and the projector 7.5 cm to
  the right of the IR camera (+x); surface points the projector cannot light, or the IR camera cannot
  see, have no depth. The shadows lie on the far surface to the left of depth steps (lobe rims);
with only 4-7 cm of relief they are 1-4 px wide, as the baseline predicts
(fx * b * (1/z_near - 1/z_far)).
- **Specular highlights:** the wet organ shows saturated white highlights in `rgb.png`; depth is
  missing there and where the projector's mirror reflection saturates the IR camera.
- **Dropouts:** grazing incidence (lobe rims), ragged pixels along depth discontinuities, sparse speckles.
- **Border band:** about 8 columns on the left and 2-3 rows at the top are invalid, as in registered
  Kinect depth.

Hole fraction {100 * stats['hole_fraction']:.2f} %, by cause (first matching cause in this order of
precedence: border, shadow, IR-camera occlusion, specular, dropout, speckle):

| code | cause | fraction of the image |
|---|---|---|
{causes}
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", help="output folder, e.g. data_samples/tissue")
    ap.add_argument("--seed", type=int, default=SEED)
    args = ap.parse_args(argv)
    make_sample(args.out_dir, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
