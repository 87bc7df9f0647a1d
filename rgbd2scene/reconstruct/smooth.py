"""Mesh smoothing for the capture mesh.

Methods (``smooth_mesh(mesh, method=...)``):

- ``"ray"`` (default): smoothing *along the viewing rays*. The camera of the capture sits at the
  origin of the world frame, so every vertex v lies on its pixel's ray r = v / v_z (unit z); only its
  depth changes, v' = r * z', which keeps the texture (UVs, vertex colours) registered exactly.
  The depth is diffused over the mesh adjacency (umbrella Laplacian, scipy.sparse), so only mesh
  neighbours count: triangles dropped at depth discontinuities cut the smoothing there. By default
  the diffused quantity is inverse depth 1/z, which is affine in pixel coordinates on a plane, so
  planes stay planes (z itself would bow). Boundary vertices (on an edge used by one triangle) are
  smoothed along the boundary only, so straight borders of a plane stay exact; where a border turns
  (corners, staircase rims) vertices drift by a fraction of the local depth change per pixel, which
  spreads a few pixels inwards (about 0.5 % of z at the corner of a plane tilted by 0.3 % of z per
  pixel, after 10 iterations). ``pin_boundary=True`` keeps every boundary vertex fixed instead (exact
  planes everywhere, but the rim keeps its noise). Optional bilateral weights (``edge_sigma``) keep
  creases.
- ``"taubin"``: Open3D ``filter_smooth_taubin`` (lambda/mu). It moves vertices *sideways* too, so
  vertices leave their pixel rays and the texture slides against the geometry (stats report
  ``max_off_ray_mm``: up to 18 mm on the TUM Kinect frame, mostly at rims); borders shrink.
- ``"corrective"``: Blender's CorrectiveSmooth modifier with ``use_only_smooth=True``, re-implemented
  in numpy (``smooth_type`` ``"length_weighted"`` as asked, or ``"simple"``; factor 0.5 by default,
  ``pin_boundary`` as Blender's "Pin Boundaries"). Also moves vertices sideways, and (unlike the
  ray method) its boundary vertices shrink inwards unless pinned.
- ``"none"``: a copy, unchanged.

``strength`` is the per-iteration step (ray: lambda of the diffusion, 0-1; taubin: lambda, with
mu = -(lambda + 0.03); corrective: Blender's "Factor"); ``iterations`` the number of passes.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from rgbd2scene.geometry.mesh import Mesh

METHODS = ("ray", "taubin", "corrective", "none")
#: (iterations, strength) used when not given.
DEFAULTS = {"ray": (10, 0.5), "taubin": (10, 0.5), "corrective": (5, 0.5), "none": (0, 0.0)}


def smooth_mesh(
    mesh: Mesh,
    method: str = "ray",
    strength: float | None = None,
    iterations: int | None = None,
    *,
    space: str = "inverse",
    edge_sigma: float | None = None,
    smooth_type: str = "length_weighted",
    pin_boundary: bool = False,
) -> tuple[Mesh, dict]:
    """Smooth a capture mesh; returns a new mesh (other arrays copied, texture shared) and stats.

    Parameters
    ----------
    method : "ray" | "taubin" | "corrective" | "none"
    strength : per-iteration step (see the module docstring); default per method.
    iterations : number of passes; default per method (ray 10, taubin 10, corrective 5).
    space : ray only: "inverse" (diffuse 1/z, keeps planes) or "z".
    edge_sigma : ray only: relative depth difference (e.g. 0.01 = 1 %) of a Gaussian range weight
        between neighbours (bilateral smoothing); None = plain Laplacian.
    smooth_type : corrective only: "length_weighted" or "simple" (Blender's two smooth types).
    pin_boundary : ray and corrective: boundary vertices do not move (Blender's "Pin Boundaries").

    Returns
    -------
    (mesh, stats) with method, iterations, strength, mean_displacement_mm, max_displacement_mm,
    max_off_ray_mm (largest distance of a vertex from its original pixel ray) and seconds.
    """
    t0 = time.perf_counter()
    if method not in METHODS:
        raise ValueError(f"unknown smoothing method {method!r}; choose one of {', '.join(METHODS)}")
    it_default, s_default = DEFAULTS[method]
    iterations = it_default if iterations is None else int(iterations)
    strength = s_default if strength is None else float(strength)
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")
    v0 = np.asarray(mesh.vertices, dtype=np.float64)
    extra: dict = {}

    if method == "none" or iterations == 0 or mesh.n_triangles == 0 or strength == 0.0:
        v = v0.copy()
    elif method == "ray":
        if not 0.0 < strength <= 1.0:
            raise ValueError(f"ray smoothing strength (lambda) must be in (0, 1], got {strength}")
        v = _smooth_ray(v0, mesh.triangles, strength, iterations, space, edge_sigma, pin_boundary)
        extra = {"space": space, "edge_sigma": edge_sigma, "pin_boundary": pin_boundary}
    elif method == "taubin":
        v = _smooth_taubin(mesh, strength, iterations)
        extra = {"mu": -(strength + 0.03)}
    else:
        v = _smooth_corrective(v0, mesh.triangles, strength, iterations, smooth_type, pin_boundary)
        extra = {"smooth_type": smooth_type, "pin_boundary": pin_boundary}

    dv = v - v0
    disp = np.sqrt(np.einsum("ij,ij->i", dv, dv))
    # Distance from the original pixel ray: |v x v0| / |v0| (the camera sits at the origin).
    cr = np.cross(v, v0)
    with np.errstate(invalid="ignore", divide="ignore"):
        off_ray = np.sqrt(np.einsum("ij,ij->i", cr, cr) / np.einsum("ij,ij->i", v0, v0))
    out = mesh.copy(vertices=v)
    stats = {
        "method": method,
        "iterations": iterations,
        "strength": strength,
        **extra,
        "mean_displacement_mm": float(disp.mean() * 1e3) if disp.size else 0.0,
        "max_displacement_mm": float(disp.max() * 1e3) if disp.size else 0.0,
        "max_off_ray_mm": float(np.nanmax(off_ray) * 1e3) if off_ray.size else 0.0,
        "seconds": round(time.perf_counter() - t0, 4),
    }
    return out, stats


def _edge_matrix(triangles: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """Upper-triangular CSR (lo, hi) of the undirected edges, data = number of triangles using each."""
    t = np.asarray(triangles)
    idx = np.int32 if n_vertices < 2**31 - 1 else np.int64
    i = t.astype(idx, copy=False).T.ravel()  # corners 0, 1, 2 of every triangle
    j = t[:, [1, 2, 0]].astype(idx, copy=False).T.ravel()
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    m = sp.csr_matrix((np.ones(lo.size, dtype=np.int32), (lo, hi)), shape=(n_vertices, n_vertices))
    m.sum_duplicates()
    return m


def _edge_rows(m: sp.csr_matrix) -> np.ndarray:
    return np.repeat(np.arange(m.shape[0], dtype=m.indices.dtype), np.diff(m.indptr))


def mesh_edges(triangles: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique undirected edges (lo, hi) with lo < hi and the number of triangles using each."""
    m = _edge_matrix(triangles, n_vertices)
    return _edge_rows(m).astype(np.int64), m.indices.astype(np.int64), m.data


def boundary_vertices(triangles: np.ndarray, n_vertices: int) -> np.ndarray:
    """Boolean mask of the vertices on an edge that only one triangle uses."""
    lo, hi, count = mesh_edges(triangles, n_vertices)
    mask = np.zeros(n_vertices, dtype=bool)
    b = count == 1
    mask[lo[b]] = True
    mask[hi[b]] = True
    return mask


def _smooth_ray(v0, triangles, lam, iterations, space, edge_sigma, pin_boundary=False):
    n = len(v0)
    z0 = v0[:, 2]
    if not np.all(z0 > 0):
        raise ValueError("ray smoothing needs every vertex in front of the capture camera (z > 0)")
    if space not in ("inverse", "z"):
        raise ValueError(f"unknown ray smoothing space {space!r} (inverse or z)")
    rays = v0 / z0[:, None]
    E = _edge_matrix(triangles, n)
    lo, hi = _edge_rows(E), E.indices
    is_b_edge = E.data == 1
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[lo[is_b_edge]] = True
    on_boundary[hi[is_b_edge]] = True
    # Interior vertices average all their neighbours; boundary vertices only those along boundary edges.
    deg_all = np.bincount(lo, minlength=n) + np.bincount(hi, minlength=n)
    lo_b, hi_b = lo[is_b_edge], hi[is_b_edge]
    deg_b = np.bincount(lo_b, minlength=n) + np.bincount(hi_b, minlength=n)
    deg = np.where(on_boundary, deg_b, deg_all).astype(np.float64)
    has = deg > 0
    if pin_boundary:
        has &= ~on_boundary
    q = 1.0 / z0 if space == "inverse" else z0.copy()
    if edge_sigma is None:
        A = sp.csr_matrix((np.ones(E.nnz), E.indices, E.indptr), shape=E.shape)  # same structure, no sort
        AT = A.T  # a CSC view: its matvec is as fast
        B = sp.csr_matrix((np.ones(lo_b.size), (lo_b, hi_b)), shape=E.shape)
        BT = B.T
        inv_deg = np.where(has, 1.0 / np.maximum(deg, 1.0), 0.0)
        bnd = np.flatnonzero(on_boundary)
        for _ in range(iterations):
            total = A @ q + AT @ q
            if bnd.size:
                total[bnd] = (B @ q + BT @ q)[bnd]
            q = q + lam * (inv_deg * total - q * has)
    else:
        sig = float(edge_sigma)
        if sig <= 0:
            raise ValueError(f"edge_sigma must be positive, got {edge_sigma}")
        rows = np.concatenate([lo, hi])
        cols = np.concatenate([hi, lo])
        b2 = np.concatenate([is_b_edge, is_b_edge])
        use = ~on_boundary[rows] | b2
        rows, cols = rows[use], cols[use]
        for _ in range(iterations):
            diff = q[cols] - q[rows]
            w = np.exp(-0.5 * (diff / (sig * q[rows])) ** 2)
            num = np.bincount(rows, weights=w * diff, minlength=n)
            den = np.bincount(rows, weights=w, minlength=n)
            q = q + lam * np.where(has & (den > 0), num / np.where(den > 0, den, 1.0), 0.0)
    z = 1.0 / q if space == "inverse" else q
    return rays * z[:, None]


def _smooth_taubin(mesh: Mesh, lam, iterations):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.ascontiguousarray(mesh.vertices, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.ascontiguousarray(mesh.triangles, dtype=np.int32)),
    )
    out = m.filter_smooth_taubin(
        number_of_iterations=int(iterations), lambda_filter=float(lam), mu=-(float(lam) + 0.03),
        filter_scope=o3d.geometry.FilterScope.Vertex,
    )
    return np.asarray(out.vertices).copy()


def _smooth_corrective(v0, triangles, factor, iterations, smooth_type, pin_boundary):
    """Blender CorrectiveSmooth with use_only_smooth (MOD_correctivesmooth.cc, smooth_iter__*)."""
    n = len(v0)
    lo, hi, count = mesh_edges(triangles, n)
    edge_count = (np.bincount(lo, minlength=n) + np.bincount(hi, minlength=n)).astype(np.float64)
    weight = np.ones(n)
    if pin_boundary:
        b = count == 1
        weight[lo[b]] = 0.0
        weight[hi[b]] = 0.0
    v = v0.copy()
    eps = np.finfo(np.float32).eps * 10.0
    if smooth_type == "length_weighted":
        lam = factor * 2.0  # Blender doubles it: this type is about half as strong as "simple"
        for _ in range(iterations):
            e = v[hi] - v[lo]
            length = np.sqrt(np.einsum("ij,ij->i", e, e))
            ew = e * length[:, None]
            delta = np.empty_like(v)
            for k in range(3):
                delta[:, k] = np.bincount(lo, ew[:, k], n) - np.bincount(hi, ew[:, k], n)
            div = (np.bincount(lo, length, n) + np.bincount(hi, length, n)) * edge_count
            ok = div > eps
            step = np.where(ok, lam * weight / np.where(ok, div, 1.0), 0.0)
            v += delta * step[:, None]
    elif smooth_type == "simple":
        has = edge_count > 0
        for _ in range(iterations):
            acc = np.empty_like(v)
            for k in range(3):
                acc[:, k] = np.bincount(lo, v[hi, k], n) + np.bincount(hi, v[lo, k], n)
            mean = acc / np.where(has, edge_count, 1.0)[:, None]
            f = np.where(has, factor * weight, 0.0)[:, None]
            v = v + f * (mean - v)
    else:
        raise ValueError(f"unknown corrective smooth_type {smooth_type!r} (length_weighted or simple)")
    return v
