"""The organised grid mesh of a depth map: one vertex per valid pixel, two triangles per pixel quad.

Frames and pixels follow ``conventions.py`` (CONVENTIONS.md section 1): the vertices are the
back-projected pixel centres in the capture camera frame (= the world frame), in metres. Triangles
are wound counter-clockwise seen from the camera, so their normals face the camera (n . ray < 0).

Triangles are not built across depth discontinuities: a triangle is dropped when its relative depth
range (max z - min z) / min z exceeds ``max_relative_jump`` or when the angle between its normal and
the viewing ray through its centroid exceeds ``max_grazing_deg``. Vertices no triangle uses are
dropped, so a ``Mesh`` holds only referenced vertices; ``Mesh.pixels`` keeps each vertex's pixel.
"""

from __future__ import annotations

import math
import time

import numpy as np

from rgbd2scene.conventions import backproject
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.mesh import Mesh


def _as_K(K) -> np.ndarray:
    K = np.asarray(K.K if hasattr(K, "K") else K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise UserError(f"grid mesh: bad intrinsics matrix K={K.tolist()}")
    return K



def grid_mesh(
    depth: np.ndarray,
    K,
    rgb: np.ndarray | None = None,
    *,
    max_relative_jump: float = 0.03,
    max_grazing_deg: float = 85.0,
    alternate_diagonal: bool = True,
) -> tuple[Mesh, dict]:
    """Organised grid mesh of a (hole-filled) planar depth map.

    Parameters
    ----------
    depth : (H, W) float
        Planar z in metres; NaN (or z <= 0) where there is no surface.
    K : (3, 3) array or ``Intrinsics``
        OpenCV intrinsics of the depth map.
    rgb : (H, W, 3) uint8 or None
        The registered capture image: vertex colours and texture. Without it vertices are grey.
    max_relative_jump : float
        Drop triangles whose (max z - min z) / min z exceeds this (None or inf: keep all).
    max_grazing_deg : float
        Drop triangles seen at more than this angle between face normal and viewing ray.
    alternate_diagonal : bool
        Where a quad has exactly three valid corners and the missing one is b or c (so neither of
        the standard triangles exists), add the triangle of the other diagonal: (a,c,d) or (a,d,b).
        This closes the staircase that a fixed diagonal leaves along hole boundaries.

    Returns
    -------
    (mesh, stats): stats has faces_total_possible (2 per quad), faces_candidates (corners valid),
    faces_dropped_invalid, faces_dropped_jump, faces_dropped_grazing (among the rest),
    faces_alternate_diagonal, faces_kept, vertices, vertices_valid, seconds.
    """
    t0 = time.perf_counter()
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.shape[0] < 2 or depth.shape[1] < 2:
        raise UserError(f"grid mesh: depth must be a 2-D map of at least 2x2 pixels, got shape {depth.shape}")
    K = _as_K(K)
    h, w = depth.shape
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape[:2] != (h, w) or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise UserError(f"grid mesh: RGB image of shape {rgb.shape} does not match depth {w}x{h}")
        if rgb.dtype != np.uint8:
            raise UserError(f"grid mesh: RGB image must be uint8, got {rgb.dtype}")

    z = depth.astype(np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(z) & (z > 0)
    pts = backproject(np.where(valid, z, np.nan), K).reshape(-1, 3)
    zf = pts[:, 2]

    idx = np.arange(h * w, dtype=np.int64).reshape(h, w)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    vf = valid.ravel()
    va, vb, vc, vd = vf[a], vf[b], vf[c], vf[d]
    n_quads = a.size

    tri_parts = [
        np.stack([a, c, b], axis=1)[va & vb & vc],
        np.stack([b, c, d], axis=1)[vb & vc & vd],
    ]
    n_alt = 0
    if alternate_diagonal:
        no_b = va & ~vb & vc & vd  # (a, c, d)
        no_c = va & vb & ~vc & vd  # (a, d, b)
        tri_parts += [np.stack([a, c, d], axis=1)[no_b], np.stack([a, d, b], axis=1)[no_c]]
        n_alt = int(no_b.sum() + no_c.sum())
    tris = np.concatenate(tri_parts, axis=0)
    n_candidates = len(tris)

    # Relative depth jump over the triangle.
    tz = zf[tris]
    zmin, zmax = tz.min(axis=1), tz.max(axis=1)
    if max_relative_jump is None or not math.isfinite(max_relative_jump):
        jump = np.zeros(len(tris), dtype=bool)
    else:
        jump = (zmax - zmin) > max_relative_jump * zmin
    # Grazing angle between the face normal and the ray through the centroid (camera at the origin).
    p0, p1, p2 = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    normal = np.cross(p1 - p0, p2 - p0)
    ray = p0 + p1 + p2
    if max_grazing_deg is None or max_grazing_deg >= 90.0:
        grazing = np.zeros(len(tris), dtype=bool)
    else:
        # cos(angle) = -n.r / (|n||r|); grazing when cos < cos(max); compare squares to skip sqrt.
        dot = -np.einsum("ij,ij->i", normal, ray)
        cmax = math.cos(math.radians(max_grazing_deg))
        nn = np.einsum("ij,ij->i", normal, normal) * np.einsum("ij,ij->i", ray, ray)
        grazing = (dot <= 0) | (dot * dot < (cmax * cmax) * nn)
    keep = ~jump & ~grazing
    n_jump = int(jump.sum())
    n_grazing = int((grazing & ~jump).sum())
    tris = tris[keep]

    # Reindex: keep only the referenced vertices, in pixel order.
    used = np.zeros(h * w, dtype=bool)
    used[tris.ravel()] = True
    pixels = np.flatnonzero(used)
    remap = np.full(h * w, -1, dtype=np.int64)
    remap[pixels] = np.arange(len(pixels))
    triangles = remap[tris].astype(np.int32)

    rows, cols = np.divmod(pixels, w)
    uvs = np.stack([(cols + 0.5) / w, 1.0 - (rows + 0.5) / h], axis=1).astype(np.float32)
    if rgb is not None:
        colors = np.ascontiguousarray(rgb.reshape(-1, 3)[pixels])
        texture = np.ascontiguousarray(rgb)
    else:
        colors = np.full((len(pixels), 3), 200, dtype=np.uint8)
        texture = None
    mesh = Mesh(
        vertices=np.ascontiguousarray(pts[pixels]),
        triangles=triangles,
        vertex_colors=colors,
        uvs=uvs,
        pixels=pixels.astype(np.int64),
        texture=texture,
    )
    stats = {
        "width": int(w),
        "height": int(h),
        "max_relative_jump": max_relative_jump,
        "max_grazing_deg": max_grazing_deg,
        "alternate_diagonal": bool(alternate_diagonal),
        "faces_total_possible": int(2 * n_quads),
        "faces_candidates": int(n_candidates),
        "faces_dropped_invalid": int(2 * n_quads - n_candidates),
        "faces_alternate_diagonal": n_alt,
        "faces_dropped_jump": n_jump,
        "faces_dropped_grazing": n_grazing,
        "faces_kept": int(len(triangles)),
        "vertices_valid": int(valid.sum()),
        "vertices": int(len(pixels)),
        "seconds": round(time.perf_counter() - t0, 4),
    }
    return mesh, stats
