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
    # One flat array per coordinate and per triangle corner rather than (N, 3) arrays: reductions and products
    # over a length-3 axis are several times slower in numpy, and the first touch of large temporaries is
    # much of this function's time in a fresh process. Every value is computed by the same operations as
    # np.cross and a min/max over the corners, so the kept triangles are the same.
    xf, yf, zf = pts[:, 0], pts[:, 1], pts[:, 2]

    # int32 pixel numbers (a depth map has far fewer than 2**31 pixels) halve the memory of the candidates.
    idx = np.arange(h * w, dtype=np.int32).reshape(h, w)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    vf = valid.ravel()
    va, vb, vc, vd = vf[a], vf[b], vf[c], vf[d]
    n_quads = a.size

    corner_parts = [((a, c, b), va & vb & vc), ((b, c, d), vb & vc & vd)]
    n_alt = 0
    if alternate_diagonal:
        no_b = va & ~vb & vc & vd  # (a, c, d)
        no_c = va & vb & ~vc & vd  # (a, d, b)
        corner_parts += [((a, c, d), no_b), ((a, d, b), no_c)]
        n_alt = int(np.count_nonzero(no_b) + np.count_nonzero(no_c))
    # Each corner of every candidate triangle, in the order of the parts, then of the quads.
    i0, i1, i2 = (np.concatenate([corners[k][mask] for corners, mask in corner_parts]) for k in range(3))
    n_candidates = len(i0)

    # Relative depth jump over the triangle.
    z0, z1, z2 = zf[i0], zf[i1], zf[i2]
    zmin = np.minimum(np.minimum(z0, z1), z2)
    if max_relative_jump is None or not math.isfinite(max_relative_jump):
        jump = np.zeros(n_candidates, dtype=bool)
    else:
        zmax = np.maximum(np.maximum(z0, z1), z2)
        jump = (zmax - zmin) > max_relative_jump * zmin
    if max_grazing_deg is None or max_grazing_deg >= 90.0:
        grazing = np.zeros(n_candidates, dtype=bool)
    else:
        # Grazing angle between the face normal and the ray through the centroid (camera at the origin):
        # cos(angle) = -n.r / (|n||r|); grazing when cos < cos(max); compare squares to skip sqrt.
        x0, x1, x2 = xf[i0], xf[i1], xf[i2]
        y0, y1, y2 = yf[i0], yf[i1], yf[i2]
        ex1, ey1, ez1 = x1 - x0, y1 - y0, z1 - z0
        ex2, ey2, ez2 = x2 - x0, y2 - y0, z2 - z0
        normal = np.stack([ey1 * ez2 - ez1 * ey2, ez1 * ex2 - ex1 * ez2, ex1 * ey2 - ey1 * ex2], axis=1)
        ray = np.stack([x0 + x1 + x2, y0 + y1 + y2, z0 + z1 + z2], axis=1)
        # einsum's sums of three products are not bit-equal to the written-out sums: kept on (N, 3) arrays
        dot = -np.einsum("ij,ij->i", normal, ray)
        cmax = math.cos(math.radians(max_grazing_deg))
        nn = np.einsum("ij,ij->i", normal, normal) * np.einsum("ij,ij->i", ray, ray)
        grazing = (dot <= 0) | (dot * dot < (cmax * cmax) * nn)
    keep = ~jump & ~grazing
    n_jump = int(np.count_nonzero(jump))
    n_grazing = int(np.count_nonzero(grazing & ~jump))
    tris = np.stack([i0[keep], i1[keep], i2[keep]], axis=1)

    # Reindex: keep only the referenced vertices, in pixel order.
    used = np.zeros(h * w, dtype=bool)
    used[tris.ravel()] = True
    pixels = np.flatnonzero(used)
    remap = np.full(h * w, -1, dtype=np.int32)
    remap[pixels] = np.arange(len(pixels), dtype=np.int32)
    triangles = remap[tris]

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
