"""The scene model's surfaces at any frame, in numpy: the independent geometry behind occlusion maps,
``DATASET/geometry/`` and ``verify``'s ray casting of moving and deforming scenes.

Every part's rest mesh is read from the scene folder (as the PLY stores it, the same float32 vertices Blender
builds from; cached by :mod:`~rgbd2scene.groundtruth.geometry_cache`), deformed by its
:class:`~rgbd2scene.scene.deformation.Deformation` (the one formula, on the same area-weighted rest normals)
and placed by its pose of the frame. Ray casts (Open3D, float32) report for every pixel the part's instance
id, the triangle and the barycentric coordinates of the hit, so a surface point can be followed into another
frame exactly: the same triangle, the same barycentric weights, that frame's vertices.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import invert_pose, transform_points
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.geometry.mesh import vertex_normals
from rgbd2scene.geometry.raycast import Raycaster, TriangleBlocks
from rgbd2scene.groundtruth.geometry_cache import mesh_arrays
from rgbd2scene.scene.deformation import rest_normals
from rgbd2scene.scene.model import Part, SceneDescription

#: A moved point counts as hidden when a surface lies in front of it by more than this fraction of its
#: distance (Open3D casts in float32: ~1e-6 relative; 1e-4 is 5 um at 5 cm).
OCCLUSION_REL = 1e-4


@dataclass
class _PartMesh:
    part: Part
    vertices: np.ndarray  # rest, part frame, float64 of the stored float32
    triangles: np.ndarray
    normals: np.ndarray | None  # rest normals, for deforming parts
    basis: np.ndarray | None  # the deformation's basis fields B_k (K, N) at the rest vertices
    blocks: TriangleBlocks | None = None  # made on first use (see SceneGeometry.in_view)
    reach: tuple[float, np.ndarray] | None = None  # max |n|, max |B_k| (K,): see SceneGeometry._largest_displacement


class SceneGeometry:
    """The surfaces of ``description`` (files in ``scene_dir``) at any frame.

    Parameters
    ----------
    description : the scene model.
    scene_dir : the scene folder holding each part's geometry file.
    cache : how many ray-casting scenes (one per frame and view) to keep: consecutive frames reuse them.
    """

    def __init__(self, description: SceneDescription, scene_dir: str | Path, cache: int = 3):
        self.description = description
        self.meshes: list[_PartMesh] = []
        for _, part in description.parts():
            stored, triangles = mesh_arrays(Path(scene_dir) / part.geometry)
            vertices, triangles = stored.astype(np.float64), triangles.astype(np.int64)
            normals = basis = None
            if part.deformation is not None:
                normals, basis = rest_normals(vertices, triangles), part.deformation.basis(vertices)
            self.meshes.append(_PartMesh(part, vertices, triangles, normals, basis))
        offsets = self._offsets = np.cumsum([0] + [len(m.vertices) for m in self.meshes])
        self.triangles = np.concatenate([m.triangles + o for m, o in zip(self.meshes, offsets[:-1], strict=True)])
        self._triangle_offsets = np.cumsum([0] + [len(m.triangles) for m in self.meshes])
        self.triangle_ids = np.concatenate([np.full(len(m.triangles), m.part.id, np.uint16) for m in self.meshes])
        self.static = not any(m.part.moving for m in self.meshes)
        self._cache: OrderedDict[tuple, Raycaster] = OrderedDict()
        self._vertices: OrderedDict[int, np.ndarray] = OrderedDict()
        self._in_view: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._cache_size = max(1, int(cache))
        self._static_normals: np.ndarray | None = None  # a static scene's (see _normals)
        self._known: np.ndarray | None = None  # which of them are computed, when only some are
        self._corner_order: tuple[np.ndarray, np.ndarray] | None = None  # see _triangles_around
        self._lock = threading.RLock()  # the render worker asks from two threads

    def _frame_key(self, frame: int) -> int:
        """The key of ``frame``'s vertices: 0 for every frame of a static scene."""
        return 0 if self.static else int(frame)

    def part_vertices(self, index: int, frame: int) -> np.ndarray:
        """World-frame vertices (N, 3) float64 of the ``index``-th part at ``frame``.

        A deforming part is :meth:`Deformation.displace` of its rest mesh, evaluated as
        ``rest + n * (c(t) @ B)`` with the basis fields B computed once.
        """
        m = self.meshes[index]
        local = m.vertices
        if m.part.deformation is not None:
            c = m.part.deformation.coefficients(self.description.time(frame))
            local = local + m.normals * (c @ m.basis)[:, None]
        return transform_points(m.part.pose_at(frame), local)

    def vertices(self, frame: int) -> np.ndarray:
        """World-frame vertices of every part at ``frame``, concatenated in model order (N, 3) float64."""
        key = self._frame_key(frame)
        with self._lock:
            out = self._vertices.get(key)
            if out is None:
                out = np.concatenate([self.part_vertices(i, frame) for i in range(len(self.meshes))])
                self._vertices[key] = out
                while len(self._vertices) > self._cache_size:
                    self._vertices.popitem(last=False)
            return out

    def deformed(self) -> list[tuple[int, int]]:
        """(instance id, part index) of the deforming parts (their vertices go to ``DATASET/geometry``)."""
        return [(m.part.id, i) for i, m in enumerate(self.meshes) if m.part.deformation is not None]

    def _eye_poses(self, frame: int) -> list[np.ndarray]:
        return [self.description.camera_pose(frame, eye) for eye in ("left", "right")]

    def in_view(self, frame: int, cameras) -> np.ndarray:
        """Indices (into :attr:`triangles`) of the triangles that ``frame``'s two eyes may see
        (:func:`~rgbd2scene.geometry.raycast.triangles_in_view`), computed once per frame and view.

        Each part's triangles are tested block by block in its rest frame
        (:class:`~rgbd2scene.geometry.raycast.TriangleBlocks`: the same indices, a few ms instead of 15-20 for
        the bundled sample's 609k triangles), moved by the part's pose and grown by its deformation's largest
        displacement at that frame.

        ``cameras``: the (left, right) cameras, or one camera looked through at both eyes' poses."""
        pair = tuple(cameras) if isinstance(cameras, tuple | list) else (cameras, cameras)
        key = (int(frame), pair)
        with self._lock:
            out = self._in_view.get(key)
            if out is None:
                views = list(zip(pair, self._eye_poses(frame), strict=True))
                vertices = self.vertices(frame)
                out = np.concatenate([
                    self._triangle_offsets[i] + self._blocks(m).in_view(
                        vertices[self._offsets[i]:self._offsets[i + 1]], m.triangles, views,
                        m.part.pose_at(frame), self._largest_displacement(m, frame))
                    for i, m in enumerate(self.meshes)])
                self._in_view[key] = out
                while len(self._in_view) > self._cache_size:
                    self._in_view.popitem(last=False)
            return out

    @staticmethod
    def _blocks(m: _PartMesh) -> TriangleBlocks:
        if m.blocks is None:
            m.blocks = TriangleBlocks(m.vertices, m.triangles)
        return m.blocks

    def _largest_displacement(self, m: _PartMesh, frame: int) -> float:
        """A bound on how far ``m``'s deformation moves any vertex at ``frame`` (0 for a rigid part):
        |n_i (c . B_i)| <= max |n| * sum_k |c_k| max_i |B_k,i|."""
        if m.part.deformation is None:
            return 0.0
        if m.reach is None:
            m.reach = (float(np.linalg.norm(m.normals, axis=1).max(initial=0.0)),
                       np.abs(m.basis).max(axis=1, initial=0.0))
        c = m.part.deformation.coefficients(self.description.time(frame))
        return m.reach[0] * float(np.abs(c) @ m.reach[1]) * (1 + 1e-9)

    def raycaster(self, frame: int, camera: Camera | None = None, T_world_cam: np.ndarray | None = None) -> Raycaster:
        """The scene at ``frame`` ready for ray casting from ``camera`` at ``T_world_cam``.

        When that camera is at one of the model's eyes at ``frame``, only the triangles ``camera`` can see
        from the two eyes are cast against (:meth:`in_view`: the same hits, and a few thousand triangles
        instead of the whole deforming tissue to build an acceleration structure over, every frame);
        otherwise, or without a camera, the whole scene.
        """
        culled = (camera is not None and T_world_cam is not None
                  and any(np.array_equal(T_world_cam, e) for e in self._eye_poses(frame)))
        key: tuple = (self._frame_key(frame),)
        if culled:
            key += (camera,)
            if self.static:  # the camera moves: the view changes with the frame
                key += (int(frame),)
        with self._lock:
            rc = self._cache.get(key)
            if rc is None:
                subset = self.in_view(frame, camera) if culled else None
                rc = Raycaster(self.vertices(frame), self.triangles, subset, self._normals(frame, subset))
                self._cache[key] = rc
                while len(self._cache) > self._cache_size:
                    self._cache.popitem(last=False)
            self._cache.move_to_end(key)
            return rc

    def _normals(self, frame: int, subset: np.ndarray | None) -> np.ndarray | None:
        """Angle-weighted vertex normals for a ray caster of ``frame``.

        For a cast against ``subset``: those of the vertices of its triangles (zero elsewhere), computed on the
        triangles around them only (every triangle sharing a vertex with one, in the mesh's order, so each
        vertex's sum has the same terms in the same order as over the whole mesh: the same bits), a few
        thousand triangles instead of the whole mesh. A static scene's are kept from frame to frame (each vertex's
        normal is computed the first time a frame needs it). For the whole scene: a static scene's, once; None
        for a moving one (the caster computes them).
        """
        vertices = self.vertices(frame)
        if subset is None:
            if self.static and (self._static_normals is None or self._known is not None):
                self._static_normals, self._known = vertex_normals(vertices, self.triangles, "angle"), None
            return self._static_normals if self.static else None
        if self.static:
            return self._static_normals_of(vertices, subset)
        around = self.triangles[self._triangles_around(subset)]
        used, corners = np.unique(around, return_inverse=True)
        out = np.zeros((len(vertices), 3))
        out[used] = vertex_normals(vertices[used], corners.reshape(-1, 3), "angle")
        return out

    def _static_normals_of(self, vertices: np.ndarray, subset: np.ndarray) -> np.ndarray:
        """A static scene's vertex normals, right at least at the vertices of ``subset``'s triangles: those not
        known yet are computed (from the triangles around them, as :meth:`_normals`) into the array kept for
        every frame; the others are left as they are (casters of earlier frames read them)."""
        if self._static_normals is not None and self._known is None:
            return self._static_normals  # all of them, made for a cast against the whole scene
        if self._static_normals is None:
            self._static_normals = np.zeros((len(vertices), 3))
            self._known = np.zeros(len(vertices), bool)
        corners = self.triangles[subset]
        unknown = ~self._known[corners]
        if unknown.any():
            touching = subset[unknown.any(axis=1)]
            around = self.triangles[self._triangles_around(touching)]
            used, local = np.unique(around, return_inverse=True)
            normals = vertex_normals(vertices[used], local.reshape(-1, 3), "angle")
            new = np.unique(corners[unknown])  # each with all its triangles in ``around``: exact
            self._static_normals[new] = normals[np.searchsorted(used, new)]
            self._known[new] = True
        return self._static_normals

    def _triangles_around(self, subset: np.ndarray) -> np.ndarray:
        """Indices of every triangle sharing a vertex with one of ``subset``, ascending (from each vertex's
        list of triangles, made once: the mesh's connectivity is the same every frame)."""
        if self._corner_order is None:
            corner_vertices = self.triangles.ravel()
            order = np.argsort(corner_vertices, kind="stable")
            counts = np.bincount(corner_vertices, minlength=self._offsets[-1])  # corners per vertex
            starts = np.concatenate([[0], np.cumsum(counts)])  # = searchsorted of the sorted corners, 3x faster
            self._corner_order = order // 3, starts
        triangle_of, starts = self._corner_order
        vertices = np.unique(self.triangles[subset])
        counts = starts[vertices + 1] - starts[vertices]
        within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        return np.unique(triangle_of[np.repeat(starts[vertices], counts) + within])

    def view_support(self, index: int, frame: int, cameras) -> np.ndarray:
        """Indices of the ``index``-th part's vertices that a render of ``frame``'s two eyes (``cameras``:
        left and right, or one camera for both) needs.

        Those of its triangles in view (:meth:`in_view`) and of every triangle sharing a vertex with one:
        each vertex in view keeps all its triangles, so its smooth normal, and every hit, are those of the
        whole mesh. A render of only these (the data render masks the rest) gives the same passes, bit for
        bit, for a small part of the cost of syncing and building a BVH over the whole tissue.
        """
        m = self.meshes[index]
        first, end = self._triangle_offsets[index], self._triangle_offsets[index + 1]
        visible = self.in_view(frame, cameras)
        visible = visible[(visible >= first) & (visible < end)] - first
        seen = np.zeros(len(m.vertices), bool)
        seen[m.triangles[visible]] = True
        keep = np.zeros(len(m.vertices), bool)
        keep[m.triangles[seen[m.triangles].any(axis=1)]] = True
        return np.flatnonzero(keep)

    def cast(self, frame: int, camera: Camera, T_world_cam: np.ndarray,
             normals: str = "smooth", face_normals: bool = True, points: bool = False) -> dict[str, np.ndarray]:
        """:meth:`Raycaster.cast` of the scene at ``frame`` (with barycentric ``uvs``; with ``points``, the hit
        points: :meth:`follow`'s at ``frame``, the same bits) plus ``instance_ids`` (H, W) uint16 (0 on a miss)."""
        rc = self.raycaster(frame, camera, T_world_cam)
        hit = rc.cast(camera, T_world_cam, normals=normals, with_uvs=True, face_normals=face_normals,
                      points=points)
        tri = hit["triangle_ids"]
        hit["instance_ids"] = np.where(tri >= 0, self.triangle_ids.take(np.maximum(tri, 0)), 0).astype(np.uint16)
        return hit

    def moved_points(self, triangle_ids: np.ndarray, uvs: np.ndarray, frame: int) -> np.ndarray:
        """World positions at ``frame`` of surface points given by triangle and barycentric (u, v) (as
        :meth:`cast` reports them at any frame); NaN where ``triangle_ids`` < 0."""
        return self.follow(triangle_ids, uvs)(frame)

    def follow(self, triangle_ids: np.ndarray, uvs: np.ndarray, seen: tuple[int, np.ndarray] | None = None):
        """``frame -> (..., 3)`` world positions of the surface points (triangle, barycentric (u, v)) at
        that frame, NaN where ``triangle_ids`` < 0: :meth:`moved_points` for several frames, the corner
        indices and weights gathered once (when first needed).

        ``seen``: (frame, the points at that frame) when known already (:meth:`cast`'s ``points``): a static
        scene's points at every frame."""
        tri = np.asarray(triangle_ids)
        gathered: list = []

        def corners_and_weights():
            if not gathered:
                u, v = np.where(tri >= 0, uvs[..., 0], np.nan)[..., None], uvs[..., 1:2]
                gathered.extend([self.triangles.take(np.maximum(tri, 0), axis=0), (1.0 - u - v, u, v)])
            return gathered

        # by vertex key: a static scene's points are the same every frame
        followed: dict[int, np.ndarray] = {}
        if seen is not None:
            seen[1].flags.writeable = False  # shared by the callers
            followed[self._frame_key(seen[0])] = seen[1]

        def at(frame: int) -> np.ndarray:
            key = self._frame_key(frame)
            if key not in followed:
                corners, weights = corners_and_weights()
                vertices = self.vertices(frame)
                # 0 + w0 p0 + w1 p1 + w2 p2 in this order, as sum() added them (its 0 turns -0.0 into 0.0: the
                # same bits), in two buffers
                point, term = vertices.take(corners[..., 0], axis=0), np.empty(corners.shape)
                point *= weights[0]
                point += 0
                for k in (1, 2):
                    vertices.take(corners[..., k], axis=0, out=term)
                    term *= weights[k]
                    point += term
                point.flags.writeable = False  # shared by the callers
                followed[key] = point
            return followed[key]

        return at

    def hidden(self, points: np.ndarray, camera: Camera, T_world_cam: np.ndarray, frame: int) -> np.ndarray:
        """Bool (...): each world point (NaN: False) is hidden from ``camera`` at ``T_world_cam`` at ``frame``:
        it projects outside the image (or behind the camera, or beyond the lens's fold), or another surface
        of that frame lies in front of it."""
        p = np.asarray(points, dtype=np.float64)
        valid = np.all(np.isfinite(p), axis=-1)
        if not valid.any():
            return valid
        u, v = camera.project(transform_points(invert_pose(T_world_cam), p, planar=True))
        inside = camera.in_image(u, v)
        centre = np.asarray(T_world_cam, dtype=np.float64)[:3, 3]
        # only points that project into the image are cast at: the segment to such a point lies in the
        # camera's view (the others are hidden anyway, and a NaN ray has no defined hit)
        directions = np.where(inside[..., None], p - centre, (0.0, 0.0, 1.0))
        rc = self.raycaster(frame, camera, T_world_cam)
        blocked = rc.blocked(centre, directions, 1.0 - OCCLUSION_REL)  # t = 1 at the point itself
        return valid & (~inside | blocked)


def occlusion_maps(geometry: SceneGeometry, frame: int, frames: int, eye: str, camera: Camera,
                   hit: dict | None = None, moved_to=None) -> dict[str, np.ndarray]:
    """``occluded_forward`` / ``occluded_backward`` (H, W) bool of one eye (seen through ``camera``) at ``frame``
    (CONVENTIONS §3).

    The surface point under each pixel (ray cast of the model, or ``hit``, that cast already made) is followed
    to the next / previous frame (same triangle and barycentric weights, that frame's vertices) and looked at
    from that frame's camera: occluded when it leaves the image or another surface hides it. Pixels without
    surface are False; on the last (first) frame, where there is no next (previous) frame, every surface
    pixel is True.
    """
    description = geometry.description
    if hit is None:
        hit = geometry.cast(frame, camera, description.camera_pose(frame, eye), normals="none")
    surface = hit["triangle_ids"] >= 0
    if moved_to is None:  # else: ``geometry.follow`` of that hit, already made (the flow's)
        moved_to = geometry.follow(hit["triangle_ids"], hit["uvs"])
    out = {}
    for key, other in (("occluded_forward", frame + 1), ("occluded_backward", frame - 1)):
        if not 0 <= other < frames:
            out[key] = surface.copy()
            continue
        moved = moved_to(other)
        out[key] = geometry.hidden(moved, camera, description.camera_pose(other, eye), other) & surface
    return out
