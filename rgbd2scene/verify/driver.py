"""Self-consistency checks of a rendered stereo dataset (``rgbd2scene verify DATASET``).

Each check is independent and compares the ground truth on disk (CONVENTIONS.md sections 3-4) with an
independent computation:

- ``schema``: keys, dtypes and shapes of every npz, NaN (never a sentinel) where there is no surface,
  unit normals facing the camera, positive disparity, K and the rig (right = left + baseline along x).
- ``depth``: against ray casting the scene mesh at the recorded K and pose (median / p99 error over
  pixels valid in both, and the valid masks, allowing a thin band of mismatch at silhouettes).
- ``normals``: against the mesh's interpolated angle-weighted vertex normals at the ray-cast hits (what
  a smooth-shaded render shows); the angle to the face normal is reported for information.
- ``disparity``: equals fx*B/z.
- ``flow_fwd`` / ``flow_bwd``: against reprojecting depth with K and the poses of the next / previous
  frame (static objects), and NaN on the last / first frame.
- ``stereo``: left/right depth agree through the disparity (left (u, v) sees what right (u - d, v) sees)
  wherever the other eye is not occluded.
- ``coverage``: fraction of pixels with surface (a warning, not a failure, below 95 %).

``verify_dataset`` returns a :class:`VerifyReport` (``report.ok``); ``format_report`` prints it.
With ``error_maps=DIR`` it also draws, per eye, the worst frame of the depth check (and of the flow check,
where that is another frame) as a PNG of labelled panels: dataset and ray-cast depth, |depth error|,
normal angle error, flow endpoint error and left/right disparity mismatch (:func:`render_error_map`).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import backproject, flow_between_cameras, invert_pose, pixel_rays, project, transform_points
from rgbd2scene.dataset import layout as ds
from rgbd2scene.errors import UserError
from rgbd2scene.files.images import write_image
from rgbd2scene.groundtruth.schema import BACKGROUND_DEPTH, SCHEMA

EYES = ds.EYES
CHECKS = ("schema", "coverage", "depth", "normals", "disparity", "flow_fwd", "flow_bwd", "stereo", "occlusion")



@dataclass
class Tolerances:
    """Pass limits of every check (lengths in mm, angles in degrees, flow and disparity in pixels)."""

    depth_median_mm: float = 0.01
    depth_p99_mm: float = 0.1
    mask_mismatch: float = 0.001  # fraction of pixels valid in one, not the other, outside the band
    mask_band_px: int = 1  # silhouette band where the valid masks may disagree
    depth_shift_px: float = 0.02  # sub-pixel image shift that best explains depth - ray cast (K, pixel centres)
    normal_median_deg: float = 0.1
    normal_p99_deg: float = 1.0
    disparity_rel: float = 1e-5
    flow_median_px: float = 0.01
    flow_p99_px: float = 0.1
    flow_missing: float = 0.0  # fraction of surface pixels without flow (not on the first/last frame)
    lr_threshold_px: float = 0.02  # disparity difference that counts as a disagreement
    lr_jump_px: float = 1.0  # neighbours further apart than this straddle an edge: not compared
    lr_inconsistent: float = 0.002  # fraction of compared pixels where the other eye sees further
    lr_median_px: float = 0.005
    occlusion_rel: float = 0.01  # relative depth difference that separates visible from hidden
    occlusion_disagree: float = 0.01  # fraction of surface pixels where occluded_* contradicts the geometry
    coverage_warn: float = 0.95
    normal_unit: float = 1e-3
    normal_facing: float = 1e-3  # fraction of pixels whose normal faces away from the camera
    pose_m: float = 1e-6
    K_abs: float = 1e-6


@dataclass
class CheckResult:
    """One row of the report: a metric of a check for one eye, aggregated (worst) over frames."""

    check: str
    eye: str
    metric: str
    value: float
    tolerance: float | None
    status: str  # pass, fail, warn, info, skip
    frames: int = 0
    worst_frame: int | None = None
    unit: str = ""
    note: str = ""


@dataclass
class VerifyReport:
    dataset: str
    width: int
    height: int
    frames: int
    mesh: str | None
    results: list[CheckResult] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    seconds: float = 0.0
    seconds_per_frame: float = float("nan")
    notes: list[str] = field(default_factory=list)
    error_maps: list[str] = field(default_factory=list)  # PNGs written with ``verify_dataset(error_maps=DIR)``

    @property
    def ok(self) -> bool:
        return all(r.status != "fail" for r in self.results) and bool(self.results)

    @property
    def failed(self) -> list[CheckResult]:
        return [r for r in self.results if r.status == "fail"]

    def status_of(self, check: str) -> str:
        """Worst status of one check over its rows: fail > warn > pass > info > skip."""
        order = ["skip", "info", "pass", "warn", "fail"]
        rows = [r.status for r in self.results if r.check == check]
        return max(rows, key=order.index) if rows else "absent"

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ok"] = self.ok
        return d


class _Metric:
    """Per-frame values of one metric; the worst one decides."""

    def __init__(self, tol: float | None, worst: str = "max", unit: str = "", warn_only: bool = False,
                 note: str = ""):
        self.tol, self.worst, self.unit, self.warn_only, self.note = tol, worst, unit, warn_only, note
        self.values: list[tuple[int, float]] = []

    def add(self, frame: int, value: float) -> None:
        if value is not None and np.isfinite(value):
            self.values.append((frame, float(value)))


class _Collector:
    def __init__(self):
        self.metrics: dict[tuple[str, str, str], _Metric] = {}
        self.skips: dict[tuple[str, str], str] = {}

    def metric(self, check: str, eye: str, name: str, tol, worst="max", unit="", warn_only=False, note=""):
        key = (check, eye, name)
        if key not in self.metrics:
            self.metrics[key] = _Metric(tol, worst, unit, warn_only, note)
        return self.metrics[key]

    def add(self, check, eye, name, frame, value, tol, worst="max", unit="", warn_only=False, note=""):
        self.metric(check, eye, name, tol, worst, unit, warn_only, note).add(frame, value)

    def results(self) -> list[CheckResult]:
        out = []
        for (check, eye, name), m in self.metrics.items():
            if not m.values:
                out.append(CheckResult(check, eye, name, float("nan"), m.tol, "skip", 0, None, m.unit,
                                       m.note or "no pixels to compare"))
                continue
            frames, vals = zip(*m.values, strict=True)
            i = int(np.argmin(vals) if m.worst == "min" else np.argmax(vals))
            value = vals[i]
            if m.tol is None:
                status = "info"
            else:
                bad = value < m.tol if m.worst == "min" else value > m.tol
                status = ("warn" if m.warn_only else "fail") if bad else "pass"
            out.append(CheckResult(check, eye, name, value, m.tol, status, len(vals), frames[i], m.unit,
                                   m.note))
        for (check, eye), reason in self.skips.items():
            out.append(CheckResult(check, eye, "-", float("nan"), None, "skip", 0, None, "", reason))
        checks, eyes = list(CHECKS), ["left", "right", "both", "L->R", "R->L"]
        out.sort(key=lambda r: (checks.index(r.check) if r.check in checks else len(checks),
                                eyes.index(r.eye) if r.eye in eyes else len(eyes)))
        return out


# ------------------------------------------------------------------------------------------------ helpers


def _object_table(meta: dict) -> dict[int, dict]:
    """dataset.json's object table as {id: {"name", "class", "moving", ...}} (list or dict form)."""
    table = meta.get("objects") or {}
    out: dict[int, dict] = {}
    items = table.items() if isinstance(table, dict) else enumerate(table) if isinstance(table, list) else []
    for key, entry in items:
        try:
            if isinstance(entry, dict):
                oid = int(entry.get("id", key))
                out[oid] = dict(entry)
            else:
                out[int(key)] = {"name": str(entry)}
        except (TypeError, ValueError):
            continue
    return out


def _silhouette_band(mask: np.ndarray, band: int) -> np.ndarray:
    """Pixels within ``band`` pixels of a boundary of ``mask`` (either side)."""
    from scipy import ndimage

    if band <= 0:
        return np.zeros_like(mask)
    st = np.ones((2 * band + 1, 2 * band + 1), bool)
    return ndimage.binary_dilation(mask, st) & ~ndimage.binary_erosion(mask, st, border_value=1)


def _stats(err: np.ndarray) -> tuple[float, float]:
    if err.size == 0:
        return float("nan"), float("nan")
    return float(np.median(err)), float(np.percentile(err, 99))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def _image_shift(depth: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    """Length (px) of the image shift (du, dv) that best explains depth - ref by ref's gradient.

    A half-pixel convention slip or a wrong principal point shows up here even where the depth
    errors themselves are tiny (gentle slopes). NaN when the surface has too little slope to tell.
    """
    gv, gu = np.gradient(ref)
    diff = depth - ref
    ok = mask & np.isfinite(gu) & np.isfinite(gv) & np.isfinite(diff)
    if ok.sum() < 16:
        return float("nan")
    g = np.stack([gu[ok], gv[ok]], axis=-1)
    d = diff[ok]
    mag = np.linalg.norm(g, axis=-1)
    keep = mag <= 10.0 * np.median(mag) + 1e-12  # leave out depth edges
    g, d = g[keep], d[keep]
    A = g.T @ g
    w = np.linalg.eigvalsh(A)
    scale = float(np.median(np.abs(ref[ok]))) * 1e-6  # slope (m/px) too small to resolve a shift
    if w[0] <= (scale**2) * len(d):
        return float("nan")
    # depth(p) = ref(p + shift)  =>  depth - ref = g . shift
    shift = np.linalg.solve(A, g.T @ d)
    return float(np.linalg.norm(shift))


def _lr_consistency(z_src: np.ndarray, z_dst: np.ndarray, fx: float, baseline: float, sign: float,
                    tol: Tolerances, out: dict | None = None) -> tuple[float, float, float, int]:
    """Compare source depth with the other eye's depth sampled where the disparity sends each pixel.

    ``sign`` = -1 for left -> right (u - d), +1 for right -> left (u + d). Returns (fraction of compared
    pixels where the other eye sees further than this eye's surface by more than the threshold, median
    |disparity difference| over non-occluded compared pixels, occluded fraction, compared count).
    With ``out`` (a dict), also puts the per-pixel map there: ``out["value"]`` |disparity difference| (px,
    float32, NaN where not compared or occluded) and ``out["state"]`` (uint8 ``_ST_*`` codes).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        d_src = np.where(z_src > 0, fx * baseline / z_src.astype(np.float64), np.nan)
        d_dst = np.where(z_dst > 0, fx * baseline / z_dst.astype(np.float64), np.nan)
    h, w = z_src.shape
    u = np.arange(w, dtype=np.float64)[None, :] + sign * d_src
    ok = np.isfinite(u) & (u >= 0) & (u <= w - 1)
    u0 = np.clip(np.floor(np.where(ok, u, 0)).astype(np.int64), 0, w - 1)
    u1 = np.minimum(u0 + 1, w - 1)
    a = np.where(ok, u, 0) - u0
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    g0, g1 = d_dst[rows, u0], d_dst[rows, u1]
    inside = ok.copy()
    sampled = np.isfinite(g0) & np.isfinite(g1)
    with np.errstate(invalid="ignore"):
        ok &= sampled & (np.abs(g0 - g1) <= tol.lr_jump_px)
    n = int(ok.sum())
    if out is not None:
        full = (1 - a) * g0 + a * g1 - d_src
        src = np.isfinite(d_src)
        state = np.full((h, w), _ST_NONE, np.uint8)
        state[src] = _ST_SKIP  # leaves the other image, or samples across a depth edge there
        state[src & inside & ~sampled] = _ST_ONE  # the other eye has no surface where this one points
        state[ok] = _ST_OK
        with np.errstate(invalid="ignore"):
            state[ok & (full > tol.lr_threshold_px)] = _ST_OCC
        value = np.full((h, w), np.nan, np.float32)
        value[state == _ST_OK] = np.abs(full[state == _ST_OK])
        out["value"], out["state"] = value, state
    if n == 0:
        return float("nan"), float("nan"), float("nan"), 0
    diff = ((1 - a) * g0 + a * g1 - d_src)[ok]  # > 0: the other eye sees something closer (occlusion)
    occluded = diff > tol.lr_threshold_px
    further = diff < -tol.lr_threshold_px
    visible = np.abs(diff[~occluded])
    return (float(further.sum() / n), float(np.median(visible)) if visible.size else float("nan"),
            float(occluded.sum() / n), n)


def _load_npz(path: Path) -> dict | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception:  # noqa: BLE001 - any unreadable file is reported, not raised
        return None


def _read_mesh(path: Path):
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    v, t = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64)
    return v, t


def _resolve_mesh(dataset_dir: Path, meta: dict, mesh_path) -> tuple[Path | None, str]:
    if mesh_path is not None:
        p = Path(mesh_path)
        if not p.is_file():
            raise UserError(f"{p}: mesh file not found")
        return p, ""
    scene = meta.get("scene") or {}
    candidates = []
    if isinstance(scene, dict):
        if scene.get("mesh"):
            candidates.append(Path(scene["mesh"]))
        if scene.get("dir"):
            candidates.append(Path(scene["dir"]) / "mesh.ply")
    for c in list(candidates):
        if not c.is_absolute():
            candidates.append(dataset_dir / c)
    for c in candidates:
        if c.is_file():
            return c, ""
    if not candidates:
        return None, "dataset.json names no scene mesh (scene.mesh); pass the mesh path"
    return None, f"scene mesh not found ({', '.join(str(c) for c in candidates)})"


# ------------------------------------------------------------------------------------------------ error maps
# Per-pixel errors of one eye and frame, kept (for the worst frame only) to draw the error-map pictures.

#: state of each pixel of an error map: compared (has an error value), no surface in either source, valid
#: in one source only, not compared (other or moving objects, depth edges, outside the other view),
#: occluded in the other eye (stereo only)
_ST_OK, _ST_NONE, _ST_ONE, _ST_SKIP, _ST_OCC = 0, 1, 2, 3, 4
#: RGB colour and legend text of the pixels without an error value
STATE_COLOURS = {
    _ST_ONE: ((255, 0, 255), "valid in one source only"),
    _ST_OCC: ((70, 130, 180), "occluded in the other eye"),
    _ST_SKIP: ((110, 110, 110), "not compared"),
    _ST_NONE: ((0, 0, 0), "no surface"),
}
#: error panel -> (unit, low, high) of its log colour scale (viridis; values are clipped to it)
ERROR_SCALES = {"depth": ("um", 1e-2, 1e3), "normals": ("deg", 1e-3, 1e2), "flow": ("px", 1e-4, 1e1),
                "stereo": ("px", 1e-4, 1e1)}
#: the panels of an error-map picture, row-major in three columns (see :func:`error_map_layout`)
ERROR_PANELS = ("depth_dataset", "depth_raycast", "depth", "normals", "flow", "stereo")


@dataclass
class ErrorPanel:
    """One per-pixel error map: ``value`` (float32, NaN where there is none) and ``state`` (uint8 ``_ST_*``)."""

    value: np.ndarray
    state: np.ndarray
    title: str
    note: str = ""


@dataclass
class FrameErrors:
    """The error maps of one eye and frame, and how far its depth / flow checks are off (``scores``)."""

    eye: str
    frame: int
    depth: np.ndarray
    ref_depth: np.ndarray | None = None
    panels: dict[str, ErrorPanel] = field(default_factory=dict)
    scores: dict[str, float] = field(default_factory=dict)  # "depth", "flow": max over metrics of value / tol


def _states(a: np.ndarray, b: np.ndarray, compared: np.ndarray) -> np.ndarray:
    """State codes from two sources' valid masks, within the ``compared`` pixels."""
    state = np.full(a.shape, _ST_NONE, np.uint8)
    state[a & b] = _ST_OK
    state[a ^ b] = _ST_ONE
    state[~compared] = _ST_SKIP
    return state


def _ratio(value: float, tol: float | None) -> float:
    if value is None or tol is None or not np.isfinite(value):
        return float("nan")
    return float(value) / max(float(tol), 1e-12)


def _worst(*ratios: float) -> float:
    vals = [r for r in ratios if not np.isnan(r)]
    return max(vals) if vals else float("nan")


def _keep_worst(keep: dict, fes: dict[str, FrameErrors]) -> None:
    """Keep, per (check, eye), the frame whose depth / flow score is the largest so far (ties: the first)."""
    for eye, fe in fes.items():
        for kind in ("depth", "flow"):
            score = fe.scores.get(kind, float("nan"))
            cur = keep.get((kind, eye))
            if not np.isnan(score) and (cur is None or score > cur.scores[kind]):
                keep[(kind, eye)] = fe


# ------------------------------------------------------------------------------------------------ checks


def _check_schema(col: _Collector, problems: list, eye: str, f: int, gt: dict, meta_K, H: int, W: int,
                  tol: Tolerances, rays: np.ndarray, last: int) -> bool:
    """Keys, dtypes, shapes, NaN masks, sentinels, unit normals facing the camera. Returns usable."""
    issues = []
    bad_keys = set()
    n_obj = None
    for key, spec in SCHEMA.items():
        dtype, shape = spec.dtype, spec.shape
        if key not in gt:
            if not spec.optional:
                issues.append(f"missing key {key}")
                bad_keys.add(key)
            continue
        a = gt[key]
        if key == "object_ids" and a.ndim == 1:
            n_obj = a.shape[0]
        sizes = {"H": H, "W": W, "N": n_obj if n_obj is not None else a.shape[0]}
        want = tuple(sizes.get(s, s) for s in shape)
        if str(a.dtype) != dtype:
            issues.append(f"{key} is {a.dtype}, not {dtype}")
            if not np.issubdtype(a.dtype, np.number):
                bad_keys.add(key)
        if a.shape != want:
            issues.append(f"{key} has shape {a.shape}, not {want}")
            bad_keys.add(key)
    usable = not bad_keys & {"depth", "K", "T_world_cam"}
    if usable:
        depth = gt["depth"].astype(np.float64)
        valid = np.isfinite(depth)
        sentinels = 0
        with np.errstate(invalid="ignore"):
            sentinels += int(np.sum(valid & ((depth <= 0) | (depth >= BACKGROUND_DEPTH))))
        sentinels += int(np.isinf(depth).sum())
        if sentinels:
            issues.append(f"depth has {sentinels} sentinel/inf values (0, negative, >= {BACKGROUND_DEPTH:g}): use NaN")
        surface = valid & (depth > 0) & (depth < BACKGROUND_DEPTH)
        mism = []
        for key in ("disparity", "normals", "flow_forward", "flow_backward"):
            a = gt.get(key)
            if a is None or a.shape[:2] != (H, W) or not np.issubdtype(a.dtype, np.floating):
                continue
            fin = np.all(np.isfinite(a), axis=-1) if a.ndim == 3 else np.isfinite(a)
            any_nan = np.any(np.isnan(a), axis=-1) if a.ndim == 3 else np.isnan(a)
            n_inf = int(np.isinf(a).sum())
            if n_inf:
                issues.append(f"{key} has {n_inf} infinite values")
            if (key == "flow_forward" and f == last) or (key == "flow_backward" and f == 0):
                if fin.any():
                    issues.append(f"{key} must be NaN on the {'last' if f == last else 'first'} frame "
                                  f"({int(fin.sum())} finite pixels)")
                continue
            if key in ("flow_forward", "flow_backward"):
                stray = fin & ~surface  # flow may be missing on surface (reported by the flow check)
                mism.append(stray.mean())
                if stray.any():
                    issues.append(f"{key} has values on {int(stray.sum())} pixels without surface")
                continue
            bad = fin != surface
            partial = any_nan & fin if a.ndim == 3 else np.zeros_like(fin)
            mism.append((bad | partial).mean())
            if bad.any():
                issues.append(f"{key}: NaN mask differs from depth's on {int(bad.sum())} pixels")
            if key == "disparity":
                with np.errstate(invalid="ignore"):
                    nonpos = int(np.sum(fin & (a <= 0)))
                if nonpos:
                    issues.append(f"disparity is not positive on {nonpos} pixels")
                    sentinels += nonpos
            if key == "normals":
                both = fin & surface
                if both.any():
                    n = a[both].astype(np.float64)
                    length = np.linalg.norm(n, axis=-1)
                    col.add("schema", eye, "normals |n|-1 (max)", f, float(np.max(np.abs(length - 1))),
                            tol.normal_unit)
                    zero = int(np.sum(length < 1e-6))
                    if zero:
                        issues.append(f"normals are zero on {zero} pixels: use NaN where there is no surface")
                        sentinels += zero
                    facing = np.sum(n * rays[both], axis=-1) >= 0
                    col.add("schema", eye, "normals not facing camera (frac)", f,
                            float(facing.mean()), tol.normal_facing)
        seg = gt.get("segmentation")
        if seg is not None and seg.shape == (H, W):
            bad = (seg != 0) != surface
            mism.append(bad.mean())
            if bad.any():
                issues.append(f"segmentation: nonzero ids differ from the depth's surface on "
                              f"{int(bad.sum())} px")
        col.add("schema", eye, "NaN/id mask mismatch (frac)", f, max(mism) if mism else 0.0, 0.0)
        col.add("schema", eye, "sentinel values (count)", f, float(sentinels), 0.0)
        K = gt["K"]
        if meta_K is not None:
            col.add("schema", eye, "K vs dataset.json (max abs)", f, float(np.max(np.abs(K - meta_K))),
                    tol.K_abs)
        T = gt["T_world_cam"]
        R = T[:3, :3]
        rigid = float(max(np.max(np.abs(R.T @ R - np.eye(3))), abs(np.linalg.det(R) - 1),
                          np.max(np.abs(T[3] - [0, 0, 0, 1]))))
        col.add("schema", eye, "T_world_cam rigidity error", f, rigid, 1e-5)
    col.add("schema", eye, "files with issues", f, float(bool(issues)), 0.0)
    for s in issues[:8]:
        problems.append(f"frame {f:06d} {eye}: {s}")
    return usable


def verify_dataset(dataset_dir, mesh_path=None, tolerances: Tolerances | None = None, *,
                   progress: bool = True, frames=None, normals: str = "smooth",
                   mesh_ids=None, error_maps: str | Path | None = None) -> VerifyReport:
    """Check a dataset folder (CONVENTIONS.md section 4) for self-consistency; see the module docstring.

    Parameters
    ----------
    dataset_dir : the dataset folder (with ``dataset.json``).
    mesh_path : the scene mesh (PLY); default ``dataset.json``'s ``scene.mesh`` (or ``scene.dir``/mesh.ply).
        Without a mesh the depth and normal checks are skipped (reported as skip).
    tolerances : pass limits (:class:`Tolerances`).
    progress : show a tqdm progress bar over frames (stderr).
    frames : optional iterable of frame numbers to check (default all).
    normals : ``"smooth"`` (interpolated vertex normals: a smooth-shaded render) or ``"face"``.
    mesh_ids : segmentation ids of the mesh's surface (default: objects of class "tissue" in the object
        table, else every id); pixels of other objects, and of moving ones, are left out of the mesh checks.
    error_maps : optional folder for error-map pictures: per eye, one PNG of the worst frame of the depth
        check (``depth_left_frame000012.png``) and, where it is another frame, one of the worst frame of
        the flow check (``flow_left_frame000007.png``); see :func:`render_error_map`. Their paths are
        listed in ``report.error_maps``. Only the worst frame's maps are held in memory.
    """
    from tqdm import tqdm

    t_start = time.perf_counter()
    tol = tolerances or Tolerances()
    root = Path(dataset_dir)
    meta_path = root / ds.DATASET_JSON
    meta = ds.read_dataset_json(root)
    try:
        W, H, n_frames = int(meta["width"]), int(meta["height"]), int(meta["frames"])
        baseline = float(meta["baseline"])
        meta_K = np.asarray(meta["K"], dtype=np.float64).reshape(3, 3) if "K" in meta else None
    except KeyError as exc:
        raise UserError(f"{meta_path}: lacks key {exc.args[0]!r}") from None
    except (TypeError, ValueError) as exc:
        raise UserError(f"{meta_path}: bad value ({exc})") from None

    maps_dir = None
    if error_maps is not None:
        from rgbd2scene.files.atomic import ensure_output_dir

        maps_dir = ensure_output_dir(error_maps)
    keep: dict[tuple[str, str], FrameErrors] | None = {} if maps_dir is not None else None

    col = _Collector()
    problems: list[str] = []
    mesh_file, mesh_reason = _resolve_mesh(root, meta, mesh_path)
    rc = None
    if mesh_file is not None:
        v, t = _read_mesh(mesh_file)
        if len(t) == 0:
            mesh_reason = f"{mesh_file}: no triangles"
        else:
            from rgbd2scene.groundtruth.raycast import raycaster

            rc = raycaster(v, t)
    if rc is None:
        for check in ("depth", "normals"):
            for eye in EYES:
                col.skips[(check, eye)] = mesh_reason

    table = _object_table(meta)
    frame_list = sorted(set(range(n_frames) if frames is None else (int(f) for f in frames)))
    last = n_frames - 1

    # Pass 1: poses and object poses of every frame (cheap: npz members load lazily).
    poses: dict[tuple[str, int], np.ndarray] = {}
    obj_poses: dict[int, list[np.ndarray]] = {}
    for eye in EYES:
        for f in range(n_frames):
            p = ds.frame_paths(root, eye, f).gt
            try:
                with np.load(p, allow_pickle=False) as z:
                    poses[(eye, f)] = np.asarray(z["T_world_cam"], dtype=np.float64)
                    if eye == "left" and "object_ids" in z.files and "object_poses" in z.files:
                        for oid, T in zip(z["object_ids"].tolist(), z["object_poses"], strict=False):
                            obj_poses.setdefault(int(oid), []).append(np.asarray(T, dtype=np.float64))
            except Exception:  # noqa: BLE001 - reported in the main pass
                pass
    moving = {oid for oid, e in table.items() if e.get("moving")}
    moving |= {oid for oid, Ts in obj_poses.items() if any(np.abs(T - Ts[0]).max() > 1e-9 for T in Ts)}
    if mesh_ids is None:
        tissue = {oid for oid, e in table.items() if str(e.get("class", "")).lower() == "tissue"}
        mesh_ids = tissue or None
    mesh_ids = None if mesh_ids is None else set(int(i) for i in mesh_ids)
    notes = []
    if moving:
        notes.append(f"moving object ids {sorted(moving)} left out of mesh and flow checks")

    # The main metrics appear in the report even when no pixel could be compared (then as skip).
    why = "no pixels to compare" + ("; moving objects are left out" if moving else "")
    for eye in EYES:
        if rc is not None:
            col.metric("depth", eye, "median abs error", tol.depth_median_mm, unit="mm", note=why)
            col.metric("normals", eye, f"median angle vs {normals} normals", tol.normal_median_deg, unit="deg",
                       note=why)
        col.metric("disparity", eye, "max rel error vs fx*B/z", tol.disparity_rel, note=why)
        if n_frames > 1:
            col.metric("flow_fwd", eye, "median endpoint error", tol.flow_median_px, unit="px", note=why)
            col.metric("flow_bwd", eye, "median endpoint error", tol.flow_median_px, unit="px", note=why)
    for pair in ("L->R", "R->L"):
        col.metric("stereo", pair, "other eye sees further (frac)", tol.lr_inconsistent, note=why)
    rays = pixel_rays(H, W, meta_K if meta_K is not None else np.eye(3))
    frame_times = []
    depth_cache: dict[tuple[str, int], np.ndarray | None] = {}

    def neighbour_depth(eye: str, g: int) -> np.ndarray | None:
        if (eye, g) not in depth_cache:
            try:
                with np.load(ds.frame_paths(root, eye, g).gt, allow_pickle=False) as z:
                    d = z["depth"]
                depth_cache[(eye, g)] = d if d.shape == (H, W) else None
            except Exception:  # noqa: BLE001 - the file is reported when its own frame is checked
                depth_cache[(eye, g)] = None
        return depth_cache[(eye, g)]
    for f in tqdm(frame_list, desc="verify", unit="frame", disable=not progress):
        t_frame = time.perf_counter()
        gts: dict[str, dict | None] = {}
        for eye in EYES:
            rgb_path, gt_path = ds.frame_paths(root, eye, f)
            gt = _load_npz(gt_path) if gt_path.is_file() else None
            if gt is None:
                problems.append(f"frame {f:06d} {eye}: {'unreadable' if gt_path.is_file() else 'missing'} "
                                f"{gt_path.relative_to(root)}")
                col.add("schema", eye, "files with issues", f, 1.0, 0.0)
                gts[eye] = None
                continue
            _check_rgb(col, problems, eye, f, rgb_path, root, H, W)
            K_eye = gt.get("K") if isinstance(gt.get("K"), np.ndarray) and gt["K"].shape == (3, 3) else meta_K
            rays_eye = pixel_rays(H, W, K_eye) if K_eye is not None else rays
            ok = _check_schema(col, problems, eye, f, gt, meta_K, H, W, tol, rays_eye, last)
            gts[eye] = gt if ok else None
            if ok:
                depth_cache[(eye, f)] = gt["depth"]
        for key in [k for k in depth_cache if k[1] < f - 1]:
            del depth_cache[key]
        fes: dict[str, FrameErrors] = {}
        for eye in EYES:
            gt = gts[eye]
            if gt is None:
                continue
            fe = FrameErrors(eye, f, gt["depth"]) if keep is not None else None
            _frame_checks(col, eye, f, gt, poses, H, W, baseline, last, tol, rc, normals, mesh_ids, moving,
                          neighbour_depth, fe)
            if fe is not None:
                fes[eye] = fe
        if gts["left"] is not None and gts["right"] is not None:
            Tl, Tr = gts["left"]["T_world_cam"], gts["right"]["T_world_cam"]
            T_lr = invert_pose(Tl) @ Tr
            expect = np.eye(4)
            expect[0, 3] = baseline
            col.add("schema", "both", "right pose vs left + baseline (max abs)", f,
                    float(np.max(np.abs(T_lr - expect))), tol.pose_m)
            col.add("schema", "both", "K left vs right (max abs)", f,
                    float(np.max(np.abs(gts["left"]["K"] - gts["right"]["K"]))), tol.K_abs)
            fx = float(gts["left"]["K"][0, 0])
            zl, zr = gts["left"]["depth"], gts["right"]["depth"]
            for eye, (a, b, sign) in (("L->R", (zl, zr, -1.0)), ("R->L", (zr, zl, 1.0))):
                out = {} if fes else None
                further, med, occ, n = _lr_consistency(a, b, fx, baseline, sign, tol, out=out)
                if n:
                    col.add("stereo", eye, "other eye sees further (frac)", f, further, tol.lr_inconsistent)
                    col.add("stereo", eye, "median |disparity diff|", f, med, tol.lr_median_px, unit="px")
                    col.add("stereo", eye, "occluded in other eye (frac)", f, occ, None)
                owner = "left" if eye == "L->R" else "right"
                if out and owner in fes:
                    note = (f"further {_fmt(100 * further, '%')}, median {_fmt(med, 'px')}, "
                            f"occluded {_fmt(100 * occ, '%')}" if n else "no pixels to compare")
                    fes[owner].panels["stereo"] = ErrorPanel(out["value"], out["state"],
                                                             f"{eye} disparity mismatch", note)
        if keep is not None:
            _keep_worst(keep, fes)
        frame_times.append(time.perf_counter() - t_frame)

    written = _write_error_maps(maps_dir, keep, tol, root.name) if keep is not None else []

    return VerifyReport(str(root), W, H, n_frames, str(mesh_file) if mesh_file else None,
                        col.results(), problems, time.perf_counter() - t_start,
                        float(np.mean(frame_times)) if frame_times else float("nan"), notes, written)


def _check_rgb(col, problems, eye, f, rgb_path: Path, root: Path, H: int, W: int) -> None:
    import cv2

    img = cv2.imread(str(rgb_path), cv2.IMREAD_UNCHANGED) if rgb_path.is_file() else None
    issue = None
    if img is None:
        issue = f"{'unreadable' if rgb_path.is_file() else 'missing'} {rgb_path.relative_to(root)}"
    elif img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        issue = f"{rgb_path.relative_to(root)} is not 8-bit RGB ({img.dtype}, shape {img.shape})"
    elif img.shape[:2] != (H, W):
        issue = f"{rgb_path.relative_to(root)} is {img.shape[1]}x{img.shape[0]}, not {W}x{H}"
    col.add("schema", eye, "rgb png issues", f, float(issue is not None), 0.0)
    if issue:
        problems.append(f"frame {f:06d} {eye}: {issue}")


def _occlusion_reference(depth, K, T_a, T_b, depth_b, rel: float):
    """Pixels of camera a whose surface point is clearly visible / clearly hidden (or outside) in b."""
    h, w = depth.shape
    surface = np.isfinite(depth)
    pts = transform_points(invert_pose(T_b) @ T_a, backproject(depth, K))
    z = pts[..., 2]
    u, v = project(pts, K)
    with np.errstate(invalid="ignore"):
        outside = surface & ~((u >= -0.5) & (u < w - 0.5) & (v >= -0.5) & (v < h - 0.5))
    inside = surface & ~outside
    u0 = np.clip(np.floor(np.nan_to_num(u)), 0, w - 2).astype(np.int64) if w > 1 else np.zeros((h, w), int)
    v0 = np.clip(np.floor(np.nan_to_num(v)), 0, h - 2).astype(np.int64) if h > 1 else np.zeros((h, w), int)
    zs = np.stack([depth_b[np.minimum(v0 + dv, h - 1), np.minimum(u0 + du, w - 1)]
                   for dv in (0, 1) for du in (0, 1)], axis=-1).astype(np.float64)
    with np.errstate(invalid="ignore"):
        close = np.any(np.abs(zs - z[..., None]) <= rel * z[..., None], axis=-1)
        hidden = np.all(zs < (z * (1 - rel))[..., None], axis=-1)  # NaN compares False: not hidden
    return inside & close, outside | (inside & hidden & ~close)


def _frame_checks(col, eye, f, gt, poses, H, W, baseline, last, tol: Tolerances, rc, normals_mode,
                  mesh_ids, moving, neighbour_depth, fe: FrameErrors | None = None) -> None:
    """The per-eye checks of one frame; with ``fe``, also keeps their per-pixel error maps there."""
    K, T = gt["K"], gt["T_world_cam"]
    depth = gt["depth"].astype(np.float64)
    with np.errstate(invalid="ignore"):
        surface = np.isfinite(depth) & (depth > 0) & (depth < BACKGROUND_DEPTH)
    seg = gt.get("segmentation")
    seg = seg if seg is not None and seg.shape == (H, W) else np.zeros((H, W), np.uint16)
    static = ~np.isin(seg, list(moving)) if moving else np.ones((H, W), bool)

    # (f) coverage
    col.add("coverage", eye, "valid pixels (min frac)", f, float(surface.mean()), tol.coverage_warn,
            worst="min", warn_only=True)

    # (c) disparity
    disp = gt.get("disparity")
    if disp is not None and disp.shape == (H, W):
        with np.errstate(divide="ignore", invalid="ignore"):
            expect = K[0, 0] * baseline / depth
        both = surface & np.isfinite(disp)
        if both.any():
            rel = np.abs(disp[both].astype(np.float64) - expect[both]) / expect[both]
            col.add("disparity", eye, "max rel error vs fx*B/z", f, float(rel.max()), tol.disparity_rel)

    # (d) flow, static surface only
    flow_maps: dict[str, tuple[float, ErrorPanel]] = {}
    for key, check, g in (("flow_forward", "flow_fwd", f + 1), ("flow_backward", "flow_bwd", f - 1)):
        flow = gt.get(key)
        if flow is None or flow.shape != (H, W, 2) or g < 0 or g > last or (eye, g) not in poses:
            continue
        ref = flow_between_cameras(np.where(surface, depth, np.nan), K, T, poses[(eye, g)]).astype(np.float64)
        ref_ok = np.all(np.isfinite(ref), axis=-1) & surface & static
        have = np.all(np.isfinite(flow), axis=-1)
        both = ref_ok & have
        med = p99 = missing = float("nan")
        if both.any():
            epe = np.linalg.norm(flow[both].astype(np.float64) - ref[both], axis=-1)
            med, p99 = _stats(epe)
            col.add(check, eye, "median endpoint error", f, med, tol.flow_median_px, unit="px")
            col.add(check, eye, "p99 endpoint error", f, p99, tol.flow_p99_px, unit="px")
        if ref_ok.any():
            missing = float((ref_ok & ~have).sum() / ref_ok.sum())
            col.add(check, eye, "surface pixels without flow (frac)", f, missing, tol.flow_missing)
        if fe is not None:
            value = np.full((H, W), np.nan, np.float32)
            if both.any():
                value[both] = epe
            title = f"{key.split('_')[1]} flow endpoint error to frame {g}"
            note = f"median {_fmt(med, 'px')}, p99 {_fmt(p99, 'px')}"
            flow_maps[key] = (_worst(_ratio(med, tol.flow_median_px), _ratio(p99, tol.flow_p99_px),
                                     _ratio(missing, tol.flow_missing)),
                              ErrorPanel(value, _states(ref_ok, have, static), title, note))
        occ_key = "occluded_forward" if key == "flow_forward" else "occluded_backward"
        occ = gt.get(occ_key)
        depth_g = neighbour_depth(eye, g)
        if occ is not None and occ.shape == (H, W) and depth_g is not None:
            visible, hidden = _occlusion_reference(np.where(surface, depth, np.nan), K, T, poses[(eye, g)],
                                                   depth_g, tol.occlusion_rel)
            occ = occ.astype(bool)
            wrong = ((occ & visible) | (~occ & hidden)) & static
            if surface.any():
                col.add("occlusion", eye, f"{occ_key} contradicting geometry (frac)", f,
                        float(wrong.sum() / surface.sum()), tol.occlusion_disagree)
    for key, boundary in (("flow_forward", last), ("flow_backward", 0)):
        flow = gt.get(key)
        if f == boundary and flow is not None and flow.shape == (H, W, 2):
            col.add("flow_fwd" if key == "flow_forward" else "flow_bwd", eye,
                    f"finite values on the {'last' if boundary else 'first'} frame (count)", f,
                    float(np.isfinite(flow).any(axis=-1).sum()), 0.0)
    if fe is not None and flow_maps:
        # The picture shows the forward flow unless there is none (last frame) or only the backward flow
        # is out of tolerance; the frame's flow score is the worse of the two directions.
        fwd, bwd = flow_maps.get("flow_forward"), flow_maps.get("flow_backward")
        show = fwd if fwd is not None and (bwd is None or not bwd[0] > max(fwd[0], 1.0)) else bwd
        fe.panels["flow"] = show[1]
        fe.scores["flow"] = _worst(*(m[0] for m in flow_maps.values()))

    # (a), (b) against the mesh
    if rc is None:
        return
    consider = static.copy()
    if mesh_ids is not None:
        consider &= np.isin(seg, list(mesh_ids)) | (seg == 0)
    if not consider.any():
        return
    cast = rc.cast(K, W, H, T, normals=normals_mode if normals_mode in ("face", "smooth") else "smooth")
    ref_depth = cast["depth"].astype(np.float64)
    ref_ok = np.isfinite(ref_depth)
    both = surface & ref_ok & consider
    med = p99 = shift = float("nan")
    if both.any():
        err_mm = np.abs(depth[both] - ref_depth[both]) * 1000.0
        med, p99 = _stats(err_mm)
        shift = _image_shift(depth, ref_depth, both)
        col.add("depth", eye, "median abs error", f, med, tol.depth_median_mm, unit="mm")
        col.add("depth", eye, "p99 abs error", f, p99, tol.depth_p99_mm, unit="mm")
        col.add("depth", eye, "image shift explaining the error", f, shift, tol.depth_shift_px, unit="px")
    mismatch = (surface != ref_ok) & consider
    band = _silhouette_band(ref_ok, tol.mask_band_px) | _silhouette_band(surface, tol.mask_band_px)
    off = float((mismatch & ~band).sum() / consider.size)
    col.add("depth", eye, "valid-mask mismatch off silhouettes (frac)", f, off, tol.mask_mismatch)
    col.add("depth", eye, "valid-mask mismatch incl. silhouettes (frac)", f,
            float(mismatch.sum() / consider.size), None)
    if fe is not None:
        fe.ref_depth = cast["depth"].astype(np.float32)
        value = np.full((H, W), np.nan, np.float32)
        if both.any():
            value[both] = err_mm * 1000.0
        note = f"median {_fmt(med * 1000.0, 'um')}, p99 {_fmt(p99 * 1000.0, 'um')}"
        fe.panels["depth"] = ErrorPanel(value, _states(surface, ref_ok, consider), "|depth error|", note)
        fe.scores["depth"] = _worst(_ratio(med, tol.depth_median_mm), _ratio(p99, tol.depth_p99_mm),
                                    _ratio(shift, tol.depth_shift_px), _ratio(off, tol.mask_mismatch))
    normals = gt.get("normals")
    if normals is not None and normals.shape == (H, W, 3):
        n_fin = np.all(np.isfinite(normals), axis=-1)
        nb = both & n_fin
        if fe is not None:
            c_fin = np.all(np.isfinite(cast["normals_cam"]), axis=-1)
            fe.panels["normals"] = ErrorPanel(np.full((H, W), np.nan, np.float32),
                                              _states(surface & n_fin, ref_ok & c_fin, consider),
                                              f"normal angle error vs {normals_mode} normals", "no pixels to compare")
        if nb.any():
            n = normals[nb].astype(np.float64)
            ang = _angle_deg(n, cast["normals_cam"][nb].astype(np.float64))
            med, p99 = _stats(ang)
            if fe is not None:
                fe.panels["normals"].value[nb] = ang
                fe.panels["normals"].note = f"median {_fmt(med, 'deg')}, p99 {_fmt(p99, 'deg')}"
            col.add("normals", eye, f"median angle vs {normals_mode} normals", f, med, tol.normal_median_deg,
                    unit="deg")
            col.add("normals", eye, f"p99 angle vs {normals_mode} normals", f, p99, tol.normal_p99_deg,
                    unit="deg")
            if "face_normals_cam" in cast:  # diagnostic: a flat-shaded render matches the face normals
                face_ang = _angle_deg(n, cast["face_normals_cam"][nb].astype(np.float64))
                col.add("normals", eye, "median angle vs face normals", f, float(np.nanmedian(face_ang)),
                        None, unit="deg")


# ------------------------------------------------------------------------------------------------ pictures

_EM_TITLE_H, _EM_LABEL_H, _EM_BAR_H, _EM_GAP = 60, 40, 34, 8
_FONT_SCALE, _TEXT = 0.5, (235, 235, 235)


def error_map_layout(width: int, height: int) -> tuple[int, int, list[tuple[int, int, int, int]]]:
    """Size of an error-map picture of ``width x height`` frames and the image box of each panel.

    Returns ``(sheet_w, sheet_h, boxes)``: one ``(x, y, w, h)`` per :data:`ERROR_PANELS` entry, three
    panels a row, each with a label strip above and its colour bar below. Panels are 384-640 px wide.
    """
    cw = int(min(max(width, 384), 640))
    ch = max(1, int(round(cw * height / width)))
    cell_h = _EM_LABEL_H + ch + _EM_BAR_H
    boxes = []
    for i in range(len(ERROR_PANELS)):
        r, c = divmod(i, 3)
        boxes.append((_EM_GAP + c * (cw + _EM_GAP), _EM_TITLE_H + _EM_GAP + r * (cell_h + _EM_GAP) + _EM_LABEL_H,
                      cw, ch))
    return 3 * cw + 4 * _EM_GAP, _EM_TITLE_H + 2 * cell_h + 3 * _EM_GAP, boxes


def colorize_error(panel: ErrorPanel, lo: float, hi: float) -> np.ndarray:
    """RGB uint8 image of an error map: viridis on a log scale clipped to [lo, hi], the states in their colours."""
    import cv2

    v = panel.value.astype(np.float64)
    ok = (panel.state == _ST_OK) & np.isfinite(v)
    t = (np.log10(np.clip(np.where(ok, v, lo), lo, hi)) - np.log10(lo)) / (np.log10(hi) - np.log10(lo))
    rgb = cv2.applyColorMap(np.round(t * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1].copy()
    for code, (colour, _) in STATE_COLOURS.items():
        rgb[panel.state == code] = colour
    rgb[(panel.state == _ST_OK) & ~ok] = STATE_COLOURS[_ST_NONE][0]
    return rgb


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = _FONT_SCALE, colour=_TEXT,
          max_width: int | None = None) -> int:
    """Draw ``text`` (shrunk to ``max_width`` if given); returns its width in pixels."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, _), _ = cv2.getTextSize(text, font, scale, 1)
    if max_width is not None and tw > max_width:
        scale *= max_width / tw
        (tw, _), _ = cv2.getTextSize(text, font, scale, 1)
    cv2.putText(img, text, org, font, scale, colour, 1, cv2.LINE_AA)
    return tw


def _scale_bar(width: int, lo: float, hi: float, log: bool, colormap: int, marks=()) -> np.ndarray:
    """A horizontal colour bar with tick labels (decades when ``log``); white ticks at ``marks``."""
    import cv2

    from rgbd2scene.pictures.overview import BACKGROUND

    img = np.full((_EM_BAR_H, width, 3), BACKGROUND, np.uint8)
    x0, x1, y0, y1 = 10, width - 10, 6, 16
    ramp = np.round(np.linspace(0.0, 1.0, x1 - x0) * 255).astype(np.uint8)[None, :]
    img[y0:y1, x0:x1] = cv2.applyColorMap(ramp, colormap)[0, :, ::-1][None]

    def pos(v: float) -> int:
        fr = (np.log10(v) - np.log10(lo)) / (np.log10(hi) - np.log10(lo)) if log else (v - lo) / (hi - lo)
        return x0 + int(round(float(np.clip(fr, 0.0, 1.0)) * (x1 - x0 - 1)))

    if log:
        ticks = [10.0**k for k in range(int(np.ceil(np.log10(lo) - 1e-9)), int(np.floor(np.log10(hi) + 1e-9)) + 1)]
    else:
        ticks = list(np.linspace(lo, hi, 5))
    for i, v in enumerate(ticks):
        x = pos(v)
        cv2.line(img, (x, y1), (x, y1 + 3), (220, 220, 220), 1)
        label = f"{v:g}" if log else f"{v:.4g}"
        if log and i == len(ticks) - 1:
            label = ">=" + label
        (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        _text(img, label, (int(np.clip(x - tw // 2, 0, width - tw)), y1 + 15), 0.4)
    for v in marks:
        if lo <= v <= hi:
            x = pos(v)
            cv2.line(img, (x, 0), (x, y1 - 1), (255, 255, 255), 1)
    return img


def render_error_map(fe: FrameErrors, kind: str, tol: Tolerances | None = None, dataset: str = "") -> np.ndarray:
    """The error-map picture (RGB uint8) of one eye and frame; ``kind`` ("depth" or "flow") names the check
    whose worst frame it is. Panels (:func:`error_map_layout`): dataset depth, ray-cast depth (one turbo
    scale, mm), |depth error| (um), normal angle error (deg), flow endpoint error (px) and left/right
    disparity mismatch (px), the errors on clipped log scales with the tolerances marked on their bars.
    """
    import cv2

    from rgbd2scene.pictures.overview import BACKGROUND, colorize_depth, depth_range, fit_cell

    tol = tol or Tolerances()
    H, W = fe.depth.shape
    sheet_w, sheet_h, boxes = error_map_layout(W, H)
    sheet = np.full((sheet_h, sheet_w, 3), BACKGROUND, np.uint8)
    score = fe.scores.get(kind, float("nan"))
    head = f"{dataset + ': ' if dataset else ''}{fe.eye} eye, frame {fe.frame} - worst frame of the {kind} check"
    if np.isfinite(score):
        head += f" (worst metric at {score:.3g} x its tolerance)"
    _text(sheet, head, (_EM_GAP, 24), 0.6, max_width=sheet_w - 2 * _EM_GAP)
    x = _EM_GAP
    for colour, text in list(STATE_COLOURS.values()):
        cv2.rectangle(sheet, (x, 38), (x + 14, 52), colour, -1)
        cv2.rectangle(sheet, (x, 38), (x + 14, 52), (200, 200, 200), 1)
        x += 20 + _text(sheet, text, (x + 20, 50), 0.45) + 16
    _text(sheet, "| on a bar: tolerance (median, p99)", (x, 50), 0.45)

    lo, hi = depth_range(fe.depth, fe.ref_depth)
    depth_bar = _scale_bar(boxes[0][2], 1000 * lo, 1000 * hi, False, cv2.COLORMAP_TURBO)
    valid = float(np.isfinite(fe.depth).mean())
    cells = [(colorize_depth(fe.depth, lo, hi), "dataset depth [mm]", f"{100 * valid:.1f} % with surface",
              depth_bar)]
    if fe.ref_depth is not None:
        hit = float(np.isfinite(fe.ref_depth).mean())
        cells.append((colorize_depth(fe.ref_depth, lo, hi), "ray-cast depth (scene mesh) [mm]",
                      f"{100 * hit:.1f} % hit", depth_bar))
    else:
        cells.append((None, "ray-cast depth", "no scene mesh", None))
    marks = {"depth": (1000 * tol.depth_median_mm, 1000 * tol.depth_p99_mm),
             "normals": (tol.normal_median_deg, tol.normal_p99_deg),
             "flow": (tol.flow_median_px, tol.flow_p99_px), "stereo": (tol.lr_median_px, tol.lr_threshold_px)}
    missing = {"depth": "no scene mesh", "normals": "no normals or no scene mesh", "flow": "no flow to check",
               "stereo": "other eye missing"}
    for key in ERROR_PANELS[2:]:
        panel = fe.panels.get(key)
        unit, elo, ehi = ERROR_SCALES[key]
        if panel is None:
            cells.append((None, key, missing[key], None))
            continue
        n_one = int((panel.state == _ST_ONE).sum())
        note = panel.note + (f"; {n_one} px in one only" if n_one else "")
        cells.append((colorize_error(panel, elo, ehi), f"{panel.title} [{unit}, log]", note,
                      _scale_bar(boxes[0][2], elo, ehi, True, cv2.COLORMAP_VIRIDIS, marks[key])))
    for (x, y, w, h), (img, title, note, bar) in zip(boxes, cells, strict=True):
        _text(sheet, title, (x + 2, y - _EM_LABEL_H + 16), max_width=w - 4)
        _text(sheet, note, (x + 2, y - 8), 0.42, (200, 200, 200), max_width=w - 4)
        if img is None:
            sheet[y:y + h, x:x + w] = (45, 45, 45)
            _text(sheet, "not available", (x + 10, y + h // 2), 0.55)
        else:
            sheet[y:y + h, x:x + w] = fit_cell(img, w, h)
        if bar is not None:
            sheet[y + h:y + h + _EM_BAR_H, x:x + w] = bar
    return sheet


def _write_error_maps(out_dir: Path, keep: dict, tol: Tolerances, dataset: str) -> list[str]:
    """Write the kept worst frames' pictures (atomically); returns their paths."""


    written = []
    for eye in EYES:
        depth_fe, flow_fe = keep.get(("depth", eye)), keep.get(("flow", eye))
        jobs = [("depth", depth_fe)] if depth_fe is not None else []
        if flow_fe is not None and (depth_fe is None or flow_fe.frame != depth_fe.frame):
            jobs.append(("flow", flow_fe))
        for kind, fe in jobs:
            path = out_dir / f"{kind}_{eye}_frame{fe.frame:06d}.png"
            img = render_error_map(fe, kind, tol, dataset)
            try:
                write_image(path, img)
            except OSError:
                raise UserError(f"{path}: could not write the error map") from None
            written.append(str(path))
    return written


# ------------------------------------------------------------------------------------------------ report


def _fmt(value: float, unit: str) -> str:
    if value is None or not np.isfinite(value):
        return "-"
    if value == 0:
        s = "0"
    elif abs(value) >= 1e4 or abs(value) < 1e-3:
        s = f"{value:.2e}"
    else:
        s = f"{value:.4g}"
    return f"{s} {unit}".strip()


def format_report(report: VerifyReport, max_problems: int = 20) -> str:
    """Plain-text table (check, eye, frames, metric, value, tolerance, result), problems, verdict."""
    header = ("check", "eye", "frames", "metric", "value", "tolerance", "result")
    rows = []
    for r in report.results:
        worst = f" (worst {r.worst_frame})" if r.frames > 1 else ""
        frames = f"{r.frames}{worst}" if r.frames else "-"
        if r.tolerance is None:
            tol = "-"
        else:
            op = ">=" if r.check == "coverage" else "<="
            tol = f"{op} {_fmt(r.tolerance, r.unit)}"
        result = r.status.upper() if r.status in ("fail", "warn") else r.status
        metric = r.metric if not r.note or r.status != "skip" else f"{r.metric} ({r.note})"
        rows.append((r.check, r.eye, frames, metric, _fmt(r.value, r.unit), tol, result))
    widths = [max(len(h), *(len(row[i]) for row in rows)) if rows else len(h) for i, h in enumerate(header)]
    line = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [f"dataset {report.dataset}: {report.width}x{report.height}, {report.frames} frames; "
           f"mesh {report.mesh or '(none)'}", line.format(*header), line.format(*("-" * w for w in widths))]
    out += [line.format(*row) for row in rows]
    if report.notes:
        out.append("")
        out += [f"note: {n}" for n in report.notes]
    if report.problems:
        out.append("")
        out.append(f"problems ({len(report.problems)}):")
        out += [f"  {p}" for p in report.problems[:max_problems]]
        if len(report.problems) > max_problems:
            out.append(f"  ... and {len(report.problems) - max_problems} more")
    if report.error_maps:
        out.append("")
        out.append(f"error maps ({len(report.error_maps)}):")
        out += [f"  {p}" for p in report.error_maps]
    failed = report.failed
    warns = [r for r in report.results if r.status == "warn"]
    verdict = "PASS" if report.ok else f"FAIL ({len(failed)} failed: " + ", ".join(
        sorted({f'{r.check}/{r.eye}' for r in failed})) + ")"
    if warns:
        verdict += f"; {len(warns)} warning(s)"
    out.append("")
    out.append(f"{verdict}  [{report.seconds:.1f} s]")
    return "\n".join(out)
