"""The triangle mesh every stage shares (:class:`Mesh`: capture, reconstruction, scene, ground truth, files).

Vertices are in metres in the frame their producer states (a capture's mesh: the capture camera frame = the
world frame, CONVENTIONS.md section 1); triangles are wound counter-clockwise seen from the outside.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass
class Mesh:
    """A triangle mesh in the capture camera frame (metres), optionally with its capture texture.

    vertices : float64 (N, 3) metres, capture camera frame (= world frame).
    triangles : int32 (M, 3), counter-clockwise seen from the camera (normals face the camera).
    vertex_colors : uint8 (N, 3) RGB, or None.
    uvs : float32 (N, 2), u = (col+0.5)/W, v = 1-(row+0.5)/H of the vertex's pixel, or None.
    pixels : int64 (N,) flat pixel index row*W+col of each vertex, or None.
    texture : uint8 (H, W, 3) RGB capture image (rows top first), or None.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    vertex_colors: np.ndarray | None = None
    uvs: np.ndarray | None = None
    pixels: np.ndarray | None = None
    texture: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return int(len(self.vertices))

    @property
    def n_triangles(self) -> int:
        return int(len(self.triangles))

    def copy(self, **changes) -> Mesh:
        """A copy that shares nothing mutable with this mesh except the texture (fields overridable)."""
        for name in ("vertices", "triangles", "vertex_colors", "uvs", "pixels"):
            if name not in changes:
                value = getattr(self, name)
                changes[name] = None if value is None else value.copy()
        return replace(self, **changes)

    def _face_cross(self) -> np.ndarray:
        v = self.vertices
        t = self.triangles
        p0, p1, p2 = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
        return np.cross(p1 - p0, p2 - p0)

    def face_normals(self) -> np.ndarray:
        """Unit normal (M, 3) of every triangle (right-hand rule on the stored winding)."""
        return _normalise(self._face_cross())

    def vertex_normals(self, weighting: str = "area") -> np.ndarray:
        """Unit vertex normals (N, 3); see :func:`vertex_normals`."""
        return vertex_normals(self.vertices, self.triangles, weighting)

    def to_open3d(self, with_texture: bool = False):
        """An ``open3d.geometry.TriangleMesh`` with vertex colours (and, if asked, UVs and texture).

        With ``with_texture`` the UVs go to ``triangle_uvs`` (the OBJ convention: v up) and the
        capture image to ``textures``, stored bottom row first as Open3D's own OBJ reader stores it
        (so texel (row', col) = (v*H - 0.5, u*W - 0.5) in Open3D's image).
        """
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.ascontiguousarray(self.vertices, dtype=np.float64)),
            o3d.utility.Vector3iVector(np.ascontiguousarray(self.triangles, dtype=np.int32)),
        )
        if self.vertex_colors is not None:
            m.vertex_colors = o3d.utility.Vector3dVector(self.vertex_colors.astype(np.float64) / 255.0)
        if with_texture and self.uvs is not None and self.texture is not None:
            tri_uvs = self.uvs[self.triangles].reshape(-1, 2).astype(np.float64)
            m.triangle_uvs = o3d.utility.Vector2dVector(tri_uvs)
            m.triangle_material_ids = o3d.utility.IntVector(np.zeros(self.n_triangles, dtype=np.int32))
            m.textures = [o3d.geometry.Image(np.ascontiguousarray(self.texture[::-1]))]
        return m


def _normalise(a: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(a, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(norm > 0, a / np.where(norm > 0, norm, 1.0), 0.0)
    return out



def vertex_normals(vertices: np.ndarray, triangles: np.ndarray, weighting: str = "area") -> np.ndarray:
    """Unit vertex normals (N, 3) from the triangle winding (right-hand rule).

    ``weighting="area"`` sums the area-weighted face normals (as Open3D does); ``"angle"`` weights
    each face by its corner angle at the vertex (Blender's smooth shading and its Normal pass).
    A vertex no triangle uses gets (0, 0, 0).
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    # Contiguous corner numbers and weights, one array per component: bincount copies a strided view at each
    # of its nine calls, and np.cross copies both inputs; the cross product is written out with np.cross's
    # own operations, so the normals are the same.
    corner_ids = [np.ascontiguousarray(t[:, k]) for k in range(3)]
    corners = [v[ids] for ids in corner_ids]
    (x1, y1, z1), (x2, y2, z2) = (corners[1] - corners[0]).T, (corners[2] - corners[0]).T
    cross = (y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2)
    if weighting == "area":
        weighted = [cross] * 3
    elif weighting == "angle":
        unit = _normalise(np.stack(cross, axis=1))
        weighted = []
        for k in range(3):
            e1 = _normalise(corners[(k + 1) % 3] - corners[k])
            e2 = _normalise(corners[(k + 2) % 3] - corners[k])
            angle = np.arccos(np.clip(np.sum(e1 * e2, axis=1), -1.0, 1.0))
            weighted.append([unit[:, d] * angle for d in range(3)])
    else:
        raise ValueError(f"unknown normal weighting {weighting!r} (area or angle)")
    acc = np.zeros((len(v), 3))
    for k in range(3):
        for d in range(3):  # bincount: much faster than np.add.at
            acc[:, d] += np.bincount(corner_ids[k], weights=weighted[k][d], minlength=len(v))
    return _normalise(acc)
