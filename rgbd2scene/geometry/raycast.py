"""Exact per-pixel depth, normals and triangle ids of a mesh by ray casting (Open3D ``RaycastingScene``).

Rays go through the pixel *centres* of this project's convention, along each pixel's own ray of the
camera (:meth:`rgbd2scene.geometry.camera.Camera.rays`: the centre of integer pixel (u, v) is at (u, v), lens
distortion inverted exactly), not through Open3D's ``create_rays_pinhole``, which shoots through
(u + 0.5 - cx) / fx. Ray directions have unit camera z, so the hit distance Open3D returns (in units of
the direction's length) is the planar depth itself.

Open3D misses about 1 ray in 1,500 that passes exactly through a mesh vertex (the capture pose puts rays
there): :func:`_recast_vertex_misses` casts such rays again from a slightly moved origin.

Used by the path generators (standoff, view coverage), ``verify`` (independent ground truth) and the
scene overview.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
from functools import lru_cache

import numpy as np

from rgbd2scene.conventions import invert_pose, rotate, transform_points
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.geometry.mesh import vertex_normals

_INVALID = np.uint32(0xFFFFFFFF)

#: Threads Open3D uses to build a scene's BVH and to cast (0: its automatic choice, every core). A process that
#: computes several frames at once (the ground-truth child) sets 1 (:func:`set_threads`): each cast then runs
#: on its caller's thread, with no pool threads waiting for work beside it.
THREADS = 0


def open3d_library():
    """Open3D's compiled library (``open3d.pybind``: ``core.Tensor``, ``t.geometry.RaycastingScene``), all a ray
    caster needs.

    ``import open3d`` also imports its visualization package, and with it ``dash``, ``plotly`` and ``IPython``
    for its web viewer: about half of its 0.7 s of CPU, paid by every process that casts rays (the render's
    ground-truth child, ``render --gt-only``, ``verify``). Where the package is not imported yet, this imports its
    extension module alone, under its own name: found by the import system's own path finder
    (:class:`importlib.machinery.PathFinder`) and loaded as the standard library's recipe for importing a
    module directly does (:func:`importlib.util.module_from_spec`, ``exec_module``), after the environment
    setting the package's ``__init__`` makes first (``TCM_ENABLE``). It is the same library:
    a later ``import open3d`` runs the package's ``__init__`` as usual and finds this module in place (the same
    classes). Anything unexpected (another layout of the package): a plain ``import open3d``.
    """
    full = sys.modules.get("open3d")
    if full is not None and hasattr(full, "t"):
        return full
    library = sys.modules.get("open3d.pybind")
    if library is not None and hasattr(library, "t"):
        return library
    inserted = False
    try:
        package = importlib.util.find_spec("open3d")  # the package's location; its __init__ is not run
        spec = importlib.machinery.PathFinder.find_spec("open3d.pybind", list(package.submodule_search_locations))
        if spec is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader):
            raise ImportError("open3d.pybind is not an extension module here")
        os.environ["TCM_ENABLE"] = "1"  # as open3d/__init__.py sets it before loading the library
        library = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = library
        inserted = True
        spec.loader.exec_module(library)
        library.t.geometry.RaycastingScene, library.core.Tensor  # noqa: B018 - what the ray caster uses
        return library
    except Exception:  # noqa: BLE001 - fall back on the whole package
        if inserted:
            sys.modules.pop("open3d.pybind", None)
        import open3d

        return open3d


def set_threads(n: int) -> None:
    """Open3D threads of this process's ray casters made from now on (:data:`THREADS`)."""
    global THREADS
    THREADS = max(0, int(n))


def _rays(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Open3D's ray layout (..., 6) float32: origin (broadcast to the directions) then direction."""
    out = np.empty(np.shape(directions)[:-1] + (6,), np.float32)
    origins, directions = np.asarray(origins, dtype=np.float64), np.asarray(directions, dtype=np.float64)
    # rounded to float32 as astype rounds; a column at a time (numpy's loops over a last axis of 3 are 6 times
    # slower on an image's rays)
    for k in range(3):
        out[..., k] = origins[..., k]
        out[..., 3 + k] = directions[..., k]
    return out


#: Relative sizes of the direction nudges tried on a ray that Open3D misses at a vertex (float32 casts:
#: a direction component of 1 has a step of 6e-8, so the first nudges move it by a few float32 steps).
VERTEX_NUDGES = (2e-7, 1e-6, 5e-6)


def _recast_vertex_misses(rc: Raycaster, hit: dict, origin: np.ndarray, directions: np.ndarray,
                          R: np.ndarray) -> dict:
    """Cast again, nudged, the image rays (H, W, 3) that missed beside a pixel that hit.

    Open3D's watertight test lets about 1 ray in 1,500 through a mesh at a shared vertex (measured: only rays
    that pass exactly through a vertex, as every ray of the capture pose does through the grid mesh built from
    that capture), and a ray along the mesh's border edge misses or hits by rounding. Such a miss beside a
    hit is cast again with its direction moved by a few float32 steps
    (:data:`VERTEX_NUDGES`, eight ways each in the camera's x-y plane (columns of ``R``), so that the hit
    distance stays planar depth); the first nudge that hits gives the pixel's hit. A ray that passes a hole or
    a silhouette farther than the largest nudge (5e-6 of its length: 0.25 um at 5 cm) stays a miss.
    """
    t = hit["t"]
    if t.ndim != 2 or t.size == 0 or np.isfinite(t).all():  # the usual view: every ray hit
        return hit
    finite = np.isfinite(directions)
    tried = ~(finite[..., 0] & finite[..., 1] & finite[..., 2])  # not .all(axis=-1): slow over 3 elements
    ways = [(a * R[:, 0] + b * R[:, 1]) / np.hypot(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if a or b]
    while True:  # a recovered hit may make its missed neighbour (a mesh corner) a suspect in turn
        missed = ~np.isfinite(hit["t"])
        pad = np.pad(~missed, 1, constant_values=False)
        beside_hit = pad[:-2, 1:-1] | pad[2:, 1:-1] | pad[1:-1, :-2] | pad[1:-1, 2:]
        rows, cols = np.nonzero(missed & beside_hit & ~tried)
        if not len(rows):
            return hit
        tried[rows, cols] = True
        d = directions[rows, cols]
        scale = np.linalg.norm(d, axis=1, keepdims=True)
        todo = np.ones(len(rows), bool)
        for size in VERTEX_NUDGES:
            for e in ways:
                idx = np.flatnonzero(todo)
                if not len(idx):
                    break
                again = rc.cast_rays(origin, d[idx] + size * scale[idx] * e)
                got = np.isfinite(again["t"])
                for key in hit:
                    hit[key][rows[idx[got]], cols[idx[got]]] = again[key][got]
                todo[idx[got]] = False
        if todo.all():
            return hit


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...) a . b of vectors (..., 3), added in their order: np.sum's value (it starts from +0, so only the sign
    of a zero may differ, which no caller looks at) in a third of the time of a reduction over 3 elements."""
    out = a[..., 0] * b[..., 0]
    out += a[..., 1] * b[..., 1]
    out += a[..., 2] * b[..., 2]
    return out


def _side(face_cam: np.ndarray, rays_cam: np.ndarray) -> np.ndarray:
    """(..., 1) -1 or 1: which side of each hit triangle (camera-frame normals ``face_cam``) the camera sees."""
    return np.where(_dot(face_cam, rays_cam) > 0, -1.0, 1.0)[..., None]


def _facing(smooth_cam: np.ndarray, rays_cam: np.ndarray, face_world: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Camera-frame smooth normals turned to face the camera (n . ray < 0).

    The same bits as turning them to the seen side of their triangle (``* side``, :func:`_side`) and then to the
    camera (:func:`~rgbd2scene.conventions.orient_normals_to_camera`): a sign flip is exact, so ``n . ray`` of the
    normal times ``side`` is ``side`` times ``n . ray``, and the flip to the camera undoes the side's wherever
    ``n . ray`` is not zero. Only where it is zero (or NaN) does the triangle's side decide, and only there are
    the face normals turned into the camera frame (the whole image's cost 7 ms per 512x256 eye)."""
    dot = _dot(smooth_cam, rays_cam)
    out = np.negative(smooth_cam, out=smooth_cam.copy(order="K"), where=(dot > 0)[..., None])
    undecided = ~(dot != 0)  # never turned above
    if undecided.any():
        side = _side(rotate(R.T, face_world[undecided]), rays_cam[undecided])
        out[undecided] *= side
    return out


def _interpolate(corners: np.ndarray, table: np.ndarray, ids: np.ndarray, uvs: np.ndarray, normals: bool = True,
                 points: bool = False):
    """Per-vertex values interpolated at hits: the normalised smooth normal (``normals``: the table's first
    three rows, NaN on a miss) and / or the point (``points``: its last three; NaN on a miss), each (..., 3).

    ``corners`` (3, M): the table columns of each triangle's three corners; ``table`` (3 or 6, N'): the values,
    a row per component; ``ids`` (...): the hit triangles (-1: miss); ``uvs`` (..., 2) their barycentric
    coordinates. Returns (normals or None, points or None).

    (1 - u - v) a0 + u a1 + v a2, summed in this order (the points from 0, as ``sum`` did: -0.0 becomes 0.0);
    the normals then divided by their length (np.linalg.norm's sqrt of the summed squares). Component by
    component: every operation runs over whole contiguous images (an (H, W, 3) layout, with (H, W, 1) weights,
    runs numpy's inner loops over 3 elements at a time, 2-3 times slower).
    """
    ids = np.asarray(ids)
    hit = ids >= 0
    every = bool(hit.all())  # the usual case: no copies of the hits
    width = 3 * (normals + points)
    if every or hit.any():
        which = ids if every else ids[hit]
        uv = uvs if every else uvs[hit]
        weights = (None, uv[..., 0], uv[..., 1])
        a, term = np.empty((width,) + which.shape), np.empty((width,) + which.shape)
        for k in range(3):
            # mode="clip": indices from ``corners`` are in range, and "raise" buffers an ``out``
            table.take(corners[k].take(which), axis=1, out=term if k else a, mode="clip")
            if k == 0:
                a *= 1.0 - weights[1] - weights[2]
                if points:
                    a[-3:] += 0
            else:
                term *= weights[k]
                a += term
        if normals:
            n = a[:3]
            with np.errstate(invalid="ignore", divide="ignore"):
                n /= np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])  # squares are never -0: norm's bits
        if not every:
            out = np.full((width,) + ids.shape, np.nan)
            out[:, hit] = a
            a = out
    else:
        a = np.full((width,) + ids.shape, np.nan)
    a = np.moveaxis(a, 0, -1)  # (..., width): components stay contiguous planes
    return (a[..., :3] if normals else None), (a[..., -3:] if points else None)


@lru_cache(maxsize=8)
def _camera_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray, bool]:
    """(:meth:`Camera.rays`, which pixels have a ray, whether all do) of ``camera``, made once (read-only): a
    ground-truth process casts through the same two cameras every frame, each time from a new ray caster."""
    rays = np.moveaxis(np.ascontiguousarray(np.moveaxis(camera.rays(), -1, 0)), 0, -1)  # planes: see rotate
    has_ray = np.isfinite(rays[..., 2])
    for a in (rays, has_ray):
        a.flags.writeable = False
    return rays, has_ray, bool(has_ray.all())


class Raycaster:
    """A triangle mesh ready for ray casting; see :func:`raycaster`.

    ``subset`` (indices into ``triangles``) casts against those triangles only, e.g. the ones a camera can
    see (:func:`triangles_in_view`): the acceleration structure is built over far fewer triangles, while
    triangle ids, barycentric coordinates and vertex normals stay those of the whole mesh. ``vertex_normals``
    (N, 3), when given, are the angle-weighted vertex normals (computed once by the caller, e.g. for a static
    scene; they need only be right at the vertices of the triangles cast against).
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, subset: np.ndarray | None = None,
                 vertex_normals: np.ndarray | None = None):
        o3d = open3d_library()  # loaded here: the CLI starts faster without it

        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
        self._subset = None if subset is None else np.asarray(subset, dtype=np.int64).ravel()
        cast = self.triangles if self._subset is None else self.triangles[self._subset]
        if cast.size and (cast.min() < 0 or cast.max() >= len(self.vertices)):
            raise ValueError("triangle indices out of range of the vertex array")
        vertices, self._used = self.vertices, None
        if self._subset is not None and cast.size:
            # only the vertices of those triangles go to Open3D (the same coordinates, so the same acceleration
            # structure and hits), not all of a large mesh's every frame
            self._used = np.unique(cast)
            vertices, cast = vertices[self._used], np.searchsorted(self._used, cast)
        # the corners of the triangles cast against, as indices into _used (all vertices when None)
        self._corners = np.ascontiguousarray(cast.T)  # (3, M): a contiguous row per corner
        self._tables: dict[tuple[bool, bool], np.ndarray] = {}
        # the hit's triangle id in the whole mesh, by the id Open3D reports (a miss: the last entry, -1)
        self._ids = None if self._subset is None else np.append(self._subset, -1)
        self._o3d = o3d
        self._threads = THREADS
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=self._threads)
        self._empty = not len(cast)
        if not self._empty:
            self._scene.add_triangles(
                o3d.core.Tensor(vertices.astype(np.float32)),
                o3d.core.Tensor(cast.astype(np.uint32)),
            )
        self._vertex_normals = vertex_normals  # given: exact at least at the vertices of ``subset``

    @property
    def vertex_normals(self) -> np.ndarray:
        """Angle-weighted unit vertex normals (computed once)."""
        if self._vertex_normals is None:
            self._vertex_normals = vertex_normals(self.vertices, self.triangles, "angle")
        return self._vertex_normals

    def cast_rays(self, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
        """First hits of rays (..., 3) in world coordinates.

        Returns ``t`` (float64, units of each direction's length, NaN on a miss), ``triangle_ids``
        (int64, -1 on a miss), ``uvs`` (barycentric (u, v): point = (1-u-v) p0 + u p1 + v p2),
        ``face_normals`` (unit, triangle winding; NaN on a miss) and ``local_ids`` (int64: the hit triangle's
        place among those this caster casts against, ``subset``'s order; -1 on a miss).
        """
        rays = _rays(origins, directions)
        shape = rays.shape[:-1]
        if rays.size == 0 or self._empty:
            return {"t": np.full(shape, np.nan), "triangle_ids": np.full(shape, -1, np.int64),
                    "uvs": np.full(shape + (2,), np.nan), "face_normals": np.full(shape + (3,), np.nan),
                    "local_ids": np.full(shape, -1, np.int64)}
        out = self._scene.cast_rays(self._o3d.core.Tensor(np.ascontiguousarray(rays.reshape(-1, 6))),
                                    nthreads=self._threads)
        t = out["t_hit"].numpy().astype(np.float64).reshape(shape)
        prim = out["primitive_ids"].numpy().reshape(shape)
        hit = (prim != _INVALID) & np.isfinite(t)
        local = np.where(hit, prim.astype(np.int64), -1)
        ids = local.copy() if self._ids is None else self._ids.take(local)  # -1: the last entry, -1
        uvs = out["primitive_uvs"].numpy().astype(np.float64).reshape(shape + (2,))
        fn = out["primitive_normals"].numpy().astype(np.float64).reshape(shape + (3,))
        if not hit.all():
            missed = ~hit
            t[missed], uvs[missed], fn[missed] = np.nan, np.nan, np.nan
        return {"t": t, "triangle_ids": ids, "uvs": uvs, "face_normals": fn, "local_ids": local}

    def blocked(self, origins: np.ndarray, directions: np.ndarray, t_max: float) -> np.ndarray:
        """Bool (...): a surface lies on each ray (..., 3) before ``t_max`` (units of the direction's
        length); an any-hit query, cheaper than :meth:`cast_rays`."""
        rays = _rays(origins, directions)
        shape = rays.shape[:-1]
        if rays.size == 0 or self._empty:
            return np.zeros(shape, bool)
        hit = self._scene.test_occlusions(self._o3d.core.Tensor(np.ascontiguousarray(rays.reshape(-1, 6))),
                                          tnear=0.0, tfar=float(t_max), nthreads=self._threads)
        return hit.numpy().astype(bool).reshape(shape)

    def smooth_normals(self, triangle_ids: np.ndarray, uvs: np.ndarray) -> np.ndarray:
        """Interpolated (then normalised) angle-weighted vertex normals at hits, world frame.

        This is the normal a smooth-shaded mesh shows (Blender/Cycles); NaN where ``triangle_ids`` < 0.
        """
        return _interpolate(self.triangles.T, self.vertex_normals.T, triangle_ids, uvs)[0]

    def _table(self, normals: bool, points: bool) -> np.ndarray:
        """Per vertex of the triangles cast against (:attr:`_corners`' indices): its vertex normal and / or its
        position, a row per component (3 or 6, N'): one gather per corner gives both, from a table of a few
        thousand vertices for a culled caster (in cache) instead of the whole mesh's."""
        table = self._tables.get((normals, points))
        if table is None:
            columns = ([self.vertex_normals] if normals else []) + ([self.vertices] if points else [])
            if self._used is not None:
                columns = [c.take(self._used, axis=0) for c in columns]
            table = np.ascontiguousarray(np.concatenate(columns, axis=1).T)
            self._tables[(normals, points)] = table
        return table

    def cast(self, camera: Camera, T_world_cam: np.ndarray, normals: str = "face",
             with_uvs: bool = False, face_normals: bool = True, points: bool = False) -> dict[str, np.ndarray]:
        """Render the mesh from ``camera`` along the ray of each pixel centre (:meth:`Camera.rays`).

        Parameters
        ----------
        camera : the camera (image size, K, distortion); pixels without a ray (beyond a lens fold) miss.
        T_world_cam : (4, 4) camera-to-world pose (OpenCV axes).
        normals : ``"face"`` (geometric triangle normals), ``"smooth"`` (interpolated angle-weighted
            vertex normals, what a smooth-shaded render shows) or ``"none"``.
        face_normals : with ``"smooth"``, whether to return the face normals too (``face_normals_cam``).
        points : whether to return the hit points, world frame, as the triangle's corners weighted by the
            barycentric coordinates (``(0 + (1-u-v) p0) + u p1 + v p2``: the bits of
            :meth:`~rgbd2scene.groundtruth.scene_geometry.SceneGeometry.follow` at this mesh's vertices).

        Returns
        -------
        dict with ``depth`` (H, W) float32 planar z (NaN on a miss), ``normals_cam`` (H, W, 3) float32
        unit normals in the camera frame facing the camera (n . ray < 0; NaN on a miss; absent for
        ``normals="none"``; with ``"smooth"`` the face normals come too, as ``face_normals_cam``),
        ``triangle_ids`` (H, W) int64 (-1 on a miss) and, with ``with_uvs``,
        ``uvs`` (H, W, 2) barycentric coordinates of the hits.
        """
        T = np.asarray(T_world_cam, dtype=np.float64)
        R, c = T[:3, :3], T[:3, 3]
        rays_cam, has_ray, every = _camera_rays(camera)  # unit z: t_hit is planar depth
        directions = rotate(R, rays_cam if every else np.where(has_ray[..., None], rays_cam, (0, 0, 1.0)),
                            planar=True)
        hit = self.cast_rays(c, directions)
        hit = _recast_vertex_misses(self, hit, c, directions, R)
        if not every:  # beyond a lens fold: no ray, nothing seen
            hit["t"][~has_ray] = np.nan
            hit["triangle_ids"][~has_ray] = -1
            hit["uvs"][~has_ray] = np.nan
            hit["face_normals"][~has_ray] = np.nan
            hit["local_ids"][~has_ray] = -1
        result = {"depth": hit["t"].astype(np.float32), "triangle_ids": hit["triangle_ids"]}
        smooth = points_world = None
        if normals == "smooth" or points:
            smooth, points_world = _interpolate(self._corners, self._table(normals == "smooth", points),
                                                hit["local_ids"], hit["uvs"], normals == "smooth", points)
        if points:
            result["points"] = points_world
        if normals == "face":
            face_cam = rotate(R.T, hit["face_normals"])  # world -> camera: R^T n
            result["normals_cam"] = (face_cam * _side(face_cam, rays_cam)).astype(np.float32)
        elif normals == "smooth":
            smooth = rotate(R.T, smooth, planar=True)
            result["normals_cam"] = _facing(smooth, rays_cam, hit["face_normals"], R).astype(np.float32)
            if face_normals:
                face_cam = rotate(R.T, hit["face_normals"])
                result["face_normals_cam"] = (face_cam * _side(face_cam, rays_cam)).astype(np.float32)
        elif normals != "none":
            raise ValueError(f"normals must be 'face', 'smooth' or 'none', not {normals!r}")
        if with_uvs:
            result["uvs"] = hit["uvs"]
        return result

    def centre_depth(self, T_world_cam: np.ndarray) -> np.ndarray | float:
        """Planar depth of the surface on the optical axis (the principal point; NaN on a miss).

        ``T_world_cam`` is one pose (4, 4), giving a float, or a stack (F, 4, 4), giving an array (F,).
        """
        T = np.asarray(T_world_cam, dtype=np.float64)
        t = self.cast_rays(T[..., :3, 3], T[..., :3, 2])["t"]
        return float(t) if T.ndim == 2 else t


def triangles_in_view(vertices: np.ndarray, triangles: np.ndarray, views, margin_px: float = 1.0) -> np.ndarray:
    """Indices of the triangles that may meet the view frustum of any of the cameras ``views``.

    A triangle is left out only when all three corners lie outside one plane of a camera's frustum (behind
    the camera, or beyond one side of the box :meth:`Camera.normalised_bounds` holding every pixel's ray and
    the image border ``margin_px`` outside the outermost pixel centres): such a triangle cannot meet a ray of
    that camera, nor a segment from its centre to a point that projects into the image. A cast against the
    rest hits exactly what a cast against the whole mesh hits, for those cameras.

    Parameters
    ----------
    vertices : (N, 3) world points; triangles : (M, 3) indices.
    views : (camera, T_world_cam) pairs: a :class:`Camera` and its camera-to-world (4, 4) pose (OpenCV axes).

    Returns
    -------
    (m,) int64 indices into ``triangles``, ascending.
    """
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    keep = np.zeros(len(tri), bool)
    for camera, T in views:
        x0, x1, y0, y1 = camera.normalised_bounds(margin_px)
        x, y, z = transform_points(invert_pose(np.asarray(T, dtype=np.float64)), vertices, planar=True).T
        # one bit per frustum plane; x / z >= x0  <=>  x - x0 z >= 0 for z > 0
        code = ((z <= 0).astype(np.uint8)
                | ((x - x0 * z < 0) << 1).astype(np.uint8)
                | ((x - x1 * z > 0) << 2).astype(np.uint8)
                | ((y - y0 * z < 0) << 3).astype(np.uint8)
                | ((y - y1 * z > 0) << 4).astype(np.uint8))
        keep |= (code[tri[:, 0]] & code[tri[:, 1]] & code[tri[:, 2]]) == 0
    return np.flatnonzero(keep)


#: Triangles per block of :class:`TriangleBlocks` (measured on the bundled 609k-triangle grid mesh: 128 builds
#: in 14 ms, 64 in 25 ms; a block's box is then about 0.2 x 0.005 x 0.02 of the mesh's 1 m x 0.65 m).
BLOCK = 128
#: Rounding allowance of a block's frustum test, relative to the size of the coordinates: the corner codes of
#: :func:`triangles_in_view` are computed with errors of a few 1e-16 of it, a block decides only beyond 1e-9.
_BLOCK_TOL = 1e-9


def _frustum_planes(camera: Camera, margin_px: float) -> np.ndarray:
    """(5, 3) camera-frame plane normals n_j of :func:`triangles_in_view`'s five codes, signed so that a
    point q is outside plane j (its code bit j set) exactly when n_j . q < 0 (z: when z <= 0)."""
    x0, x1, y0, y1 = camera.normalised_bounds(margin_px)
    return np.array([[0.0, 0.0, 1.0], [1.0, 0.0, -x0], [-1.0, 0.0, x1], [0.0, 1.0, -y0], [0.0, -1.0, y1]])


class TriangleBlocks:
    """A mesh's triangles in blocks of :data:`BLOCK` consecutive indices, each with a box holding its corners:
    :func:`triangles_in_view` of a large mesh seen in small part, the same indices, for a fraction of the cost.

    A block whose box lies beyond one frustum plane of every camera (by more than the rounding of the corner
    test) is left out whole, one whose box lies inside every plane of a camera is kept whole; only the
    triangles of blocks the frustum's border crosses get :func:`triangles_in_view`'s corner test itself. A mesh
    in spatially coherent order (a capture's grid mesh: rows of pixels) makes small boxes; any order gives
    the same indices.

    Parameters
    ----------
    vertices : (N, 3) the mesh's vertices in its own frame (a part's rest frame).
    triangles : (M, 3) indices.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, size: int = BLOCK):
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        self.count, self.size = len(tri), int(size)
        pad = (-len(tri)) % self.size
        if pad and len(tri):  # the last block repeats its last triangle: the same box
            tri = np.concatenate([tri, np.repeat(tri[-1:], pad, axis=0)])
        corners = tri.reshape(-1, self.size * 3)
        lo, hi = np.empty((len(corners), 3)), np.empty((len(corners), 3))
        for k in range(3):  # per coordinate: a gather and a row reduction of contiguous arrays
            c = np.ascontiguousarray(v[:, k]).take(corners)
            lo[:, k], hi[:, k] = c.min(axis=1), c.max(axis=1)
        self.centre, self.half = (lo + hi) / 2, (hi - lo) / 2
        self.reach = float(np.abs(self.centre).max(initial=0.0) + self.half.max(initial=0.0))

    def in_view(self, vertices: np.ndarray, triangles: np.ndarray, views, pose: np.ndarray | None = None,
                grow: float = 0.0, margin_px: float = 1.0) -> np.ndarray:
        """:func:`triangles_in_view` ``(vertices, triangles, views, margin_px)``: the same indices.

        ``vertices``: the mesh's world-frame vertices now, ``pose`` (4, 4) (default identity) times its own
        vertices moved by at most ``grow`` (a deformation's largest displacement; 0: rigid).
        """
        tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        P = np.eye(4) if pose is None else np.asarray(pose, dtype=np.float64)
        blocks = len(self.centre)
        if not blocks:
            return np.zeros(0, np.int64)
        dropped, whole = np.ones(blocks, bool), np.zeros(blocks, bool)
        for camera, T in views:
            T = np.asarray(T, dtype=np.float64)
            A = T[:3, :3].T @ P[:3, :3]  # block frame -> camera frame: q = A p + b
            b = T[:3, :3].T @ (P[:3, 3] - T[:3, 3])
            planes = _frustum_planes(camera, margin_px)
            G, h = planes @ A, planes @ b
            mid = self.centre @ G.T + h
            rad = (self.half + grow) @ np.abs(G).T
            tol = _BLOCK_TOL * np.abs(planes).sum(axis=1).max() * (self.reach + grow + np.abs(P[:3, 3]).max()
                                                                   + np.abs(T[:3, 3]).max() + 1.0)
            dropped &= (mid + rad < -tol).any(axis=1)
            whole |= (mid - rad > tol).all(axis=1)
        step = np.arange(self.size)
        kept = (np.flatnonzero(whole & ~dropped)[:, None] * self.size + step).ravel()
        border = (np.flatnonzero(~whole & ~dropped)[:, None] * self.size + step).ravel()
        border = border[border < self.count]
        if len(border):
            corners = tri[border]
            used = np.zeros(len(vertices), bool)
            used[corners] = True
            used = np.flatnonzero(used)
            local = np.empty(len(vertices), np.int64)
            local[used] = np.arange(len(used))
            # the corner test on these triangles' vertices alone: elementwise, the same codes as on all of them
            seen = triangles_in_view(np.asarray(vertices)[used], local[corners], views, margin_px)
            kept = np.concatenate([kept, border[seen]])
        kept = np.sort(kept[kept < self.count])
        return kept


def raycaster(vertices: np.ndarray, triangles: np.ndarray) -> Raycaster:
    """Wrap a triangle mesh (vertices (N, 3) metres, triangles (M, 3) indices) for ray casting."""
    return Raycaster(vertices, triangles)
