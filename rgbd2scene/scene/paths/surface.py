"""The mesh as generated paths see it: a height map along the capture direction, view footprints, placement
at a standoff, and how much of both eyes' views a path keeps on the surface."""

from __future__ import annotations

import numpy as np

from rgbd2scene.scene.paths.track import CameraPath
from rgbd2scene.scene.rig import StereoRig


class Surface:
    """The mesh seen along the capture direction (+z): an orthographic height map and its valid cells.

    ``rc`` is a ``raycast.Raycaster`` of the mesh; cells are ``cell`` metres wide (at most 1024 across).
    """

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

    def most_interior(self, region: np.ndarray) -> np.ndarray:
        """Point (x, y) of the cell of ``region`` farthest from its border."""
        from scipy import ndimage

        dist = ndimage.distance_transform_edt(region)
        r, c = np.unravel_index(np.argmax(dist), dist.shape)
        return self.to_xy(r, c)

    def region(self, half_x: float, half_y: float) -> np.ndarray:
        """Cells whose surrounding rectangle (half sizes in metres) holds only valid cells."""
        from scipy import ndimage

        rx, ry = int(np.ceil(half_x / self.cell)), int(np.ceil(half_y / self.cell))
        return ndimage.minimum_filter(self.valid.astype(np.uint8), size=(2 * ry + 1, 2 * rx + 1),
                                      mode="constant", cval=0).astype(bool)


def view_height(rig: StereoRig, depth: float) -> float:
    """Height (m) of the view at ``depth`` along the optical axis."""
    if rig.left.is_pinhole:
        return depth * rig.intrinsics.height / rig.intrinsics.fy
    _, _, y0, y1 = rig.left.normalised_bounds(0.0)  # the lens's own view: every pixel's ray
    return depth * (y1 - y0)


def footprint_half(rig: StereoRig, depth: float, tilt_rad: float) -> tuple[float, float]:
    """Half extents (x, y) on a plane at ``depth`` of both eyes' views, tilted by up to ``tilt_rad``."""
    bounds = [camera.normalised_bounds(0.0) for camera in (rig.left, rig.right)]  # every pixel's ray, any lens
    ax = np.arctan(max(max(-x0, x1) for x0, x1, _, _ in bounds))
    ay = np.arctan(max(max(-y0, y1) for _, _, y0, y1 in bounds))
    hx = depth * np.sin(ax) / np.cos(min(ax + tilt_rad, np.radians(85.0))) + rig.baseline
    hy = depth * np.sin(ay) / np.cos(min(ay + tilt_rad, np.radians(85.0)))
    return float(hx), float(hy)


def place(surface: Surface, ground_xy: np.ndarray | None, R: np.ndarray, standoff: float, smooth: float,
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


def path_coverage(vertices, triangles, rig: StereoRig, path: CameraPath, scale: float = 1.0,
                  rc=None) -> np.ndarray:
    """Fraction of pixels (F, 2) that see the surface within the rig's clip range, per frame, left/right.

    ``scale`` < 1 checks at a reduced resolution (faster); ``rc`` is a ready ``raycast.Raycaster``
    (then vertices and triangles are not used).
    """
    from rgbd2scene.geometry.raycast import raycaster

    rc = rc if rc is not None else raycaster(vertices, triangles)
    if scale != 1.0:
        intr = rig.intrinsics
        rig = rig.resized(max(2, int(round(intr.width * scale))), max(2, int(round(intr.height * scale))))
    out = np.zeros((path.frames, 2))
    for f, T in enumerate(path.T_world_cam):
        for eye, pose in enumerate((T, rig.right_pose(T))):
            depth = rc.cast(rig.camera(("left", "right")[eye]), pose, normals="none")["depth"]
            with np.errstate(invalid="ignore"):
                ok = (depth >= rig.clip_start) & (depth <= rig.clip_end)
            out[f, eye] = ok.mean()
    return out
