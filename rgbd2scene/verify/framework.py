"""The check framework of ``verify``: tolerances, the per-frame views a check reads, the metric collector.

A check is a :class:`Check` subclass in its own module under ``rgbd2scene/verify/checks/``, listed once in
``checks.CHECKS``. For every frame the driver builds one :class:`EyeFrame` per eye and calls each check's
``check_eye``, then, when both eyes are usable, one :class:`PairFrame` for ``check_pair``. A check reads

- ``frame.map(key)``: a ground-truth map of the one schema (``groundtruth.schema.SCHEMA``), or None when the
  file lacks it or it has the wrong shape (the ``schema`` check reports that);
- ``frame.depth``, ``frame.surface``, ``frame.segmentation``, ``frame.static``: derived per-pixel arrays;
- ``frame.cast``: what the scene oracle (``verify.oracle``) sees from this eye at this frame, and
  ``frame.oracle_pixels``, the pixels whose surface the oracle models;
- ``frame.pose(g)``, ``frame.depth_at(g)``: the same eye at another frame (flow, occlusion);
- ``frame.run``: the whole run (dataset, tolerances, baseline, moving object ids);

and reports with ``frame.add(check, metric, value, tolerance)`` (one value per frame; the worst over frames
decides pass or fail), ``frame.problem(text)`` (a line under "problems") and, when error maps are drawn,
panels in ``frame.errors`` (``verify.error_maps``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from rgbd2scene.dataset.layout import FramePaths, frame_paths
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.groundtruth.schema import DISTORTION_LENGTHS, SCHEMA, surface_mask

if TYPE_CHECKING:
    from rgbd2scene.dataset.reader import Dataset
    from rgbd2scene.verify.error_maps import FrameErrors
    from rgbd2scene.verify.oracle import RayCast, SceneOracle

#: Keys without which a frame is checked by the ``schema`` check only (every other check needs them).
CORE_KEYS = ("depth", "K", "T_world_cam")
#: Depth maps kept for the neighbouring frames' checks: both eyes of the previous, current and next frame.
DEPTH_CACHE = 6
#: Row order of the report within a check.
EYE_ORDER = ("left", "right", "both", "L->R", "R->L")


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
    id_mismatch: float = 0.0  # fraction of pixels off id edges whose instance id differs from the scene's
    occlusion_disagree: float = 0.005  # fraction of surface pixels where occluded_* contradicts the geometry
    coverage_warn: float = 0.95
    normal_unit: float = 1e-3
    normal_facing: float = 1e-3  # fraction of pixels whose normal faces away from the camera
    pose_m: float = 1e-6
    pose_rigidity: float = 1e-5  # max deviation of T_world_cam from a rotation plus translation
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
class Metric:
    """Per-frame values of one metric; the worst one (``worst``: "max" or "min") decides."""

    tol: float | None
    worst: str = "max"
    unit: str = ""
    warn_only: bool = False
    note: str = ""
    values: list[tuple[int, float]] = field(default_factory=list)

    def add(self, frame: int, value: float | None) -> None:
        if value is not None and np.isfinite(value):
            self.values.append((frame, float(value)))

    def result(self, check: str, eye: str, name: str) -> CheckResult:
        if not self.values:
            return CheckResult(check, eye, name, float("nan"), self.tol, "skip", 0, None, self.unit,
                               self.note or "no pixels to compare")
        frames, vals = zip(*self.values, strict=True)
        i = int(np.argmin(vals) if self.worst == "min" else np.argmax(vals))
        if self.tol is None:
            status = "info"
        else:
            bad = vals[i] < self.tol if self.worst == "min" else vals[i] > self.tol
            status = ("warn" if self.warn_only else "fail") if bad else "pass"
        return CheckResult(check, eye, name, vals[i], self.tol, status, len(vals), frames[i], self.unit, self.note)


class Collector:
    """Every metric of a run by (check, eye, metric name), in the order they first appeared, and skipped checks."""

    def __init__(self):
        self.metrics: dict[tuple[str, str, str], Metric] = {}
        self.skips: dict[tuple[str, str], str] = {}

    def metric(self, check: str, eye: str, name: str, tol: float | None, worst: str = "max", unit: str = "",
               warn_only: bool = False, note: str = "") -> Metric:
        """The metric (created with these settings when new): a metric declared here is reported even when
        it never gets a value (as skip, with ``note`` as the reason)."""
        key = (check, eye, name)
        if key not in self.metrics:
            self.metrics[key] = Metric(tol, worst, unit, warn_only, note)
        return self.metrics[key]

    def add(self, check: str, eye: str, name: str, frame: int, value: float | None, tol: float | None,
            **settings) -> None:
        self.metric(check, eye, name, tol, **settings).add(frame, value)

    def results(self, check_order: Iterable[str]) -> list[CheckResult]:
        """Rows sorted by check (``check_order``) then eye (:data:`EYE_ORDER`), metrics in order of appearance."""
        out = [m.result(*key) for key, m in self.metrics.items()]
        out += [CheckResult(check, eye, "-", float("nan"), None, "skip", 0, None, "", reason)
                for (check, eye), reason in self.skips.items()]
        checks = list(check_order)
        out.sort(key=lambda r: (checks.index(r.check) if r.check in checks else len(checks),
                                EYE_ORDER.index(r.eye) if r.eye in EYE_ORDER else len(EYE_ORDER)))
        return out


def median_p99(values: np.ndarray) -> tuple[float, float]:
    """Median and 99th percentile of a 1-D array (NaN, NaN when empty)."""
    if values.size == 0:
        return float("nan"), float("nan")
    return float(np.median(values)), float(np.percentile(values, 99))


@dataclass(eq=False)
class VerifyRun:
    """What every check may read about the whole run, and where its findings go."""

    dataset: Dataset
    width: int
    height: int
    baseline: float
    K: np.ndarray  # dataset.json's K
    tol: Tolerances
    oracle: SceneOracle | None
    moving: frozenset[int]  # ids of objects that move (left out of the static-scene checks)
    poses: dict[tuple[str, int], np.ndarray]  # T_world_cam by (eye, frame), every readable frame
    collector: Collector = field(default_factory=Collector)
    problems: list[str] = field(default_factory=list)
    _depths: dict[tuple[str, int], np.ndarray | None] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    @property
    def last(self) -> int:
        return self.dataset.frames - 1

    @property
    def rig(self):
        """The rig as rendered (dataset.json's ``camera``): both eyes' cameras and R, T."""
        return self.dataset.rig

    @property
    def rectified(self) -> bool:
        """A rectified pair (disparity); otherwise raw (correspondence, CONVENTIONS 1.2)."""
        return self.rig.rectified

    @property
    def no_pixels_note(self) -> str:
        """Why a declared metric got no value."""
        return "no pixels to compare" + ("; moving objects are left out" if self.moving else "")

    def depth(self, eye: str, index: int) -> np.ndarray | None:
        """The depth map of an eye and frame (None when unreadable or misshapen), cached for the next frames."""
        if (eye, index) not in self._depths:
            try:
                depth = self.dataset.gt(eye, index, keys=("depth",))["depth"]
            except UserError:  # reported when that frame itself is checked
                depth = None
            self.keep_depth(eye, index, depth if depth is not None and depth.shape == self.shape else None)
        return self._depths[(eye, index)]

    def keep_depth(self, eye: str, index: int, depth: np.ndarray | None) -> None:
        """Cache a depth map for the neighbouring frames' checks (the last :data:`DEPTH_CACHE` only)."""
        self._depths.pop((eye, index), None)  # re-inserted as the newest
        self._depths[(eye, index)] = depth
        while len(self._depths) > DEPTH_CACHE:
            del self._depths[next(iter(self._depths))]


@dataclass(frozen=True)
class KeyCheck:
    """The keys of one ground-truth file against the schema: what is wrong and which keys are unusable."""

    issues: tuple[str, ...]
    bad_keys: frozenset[str]


def check_keys(gt: dict[str, np.ndarray], height: int, width: int, rectified: bool = True) -> KeyCheck:
    """Missing keys, wrong dtypes and wrong shapes of a ground-truth dict (``SCHEMA``); a raw pair
    (``rectified`` False) has ``correspondence`` in place of ``disparity``."""
    issues, bad = [], set()
    count = None  # object count N, from object_ids
    swap = {} if rectified else {"disparity": True, "correspondence": False}  # key -> optional
    for key, spec in SCHEMA.items():
        if key not in gt:
            if not swap.get(key, spec.optional):
                issues.append(f"missing key {key}")
                bad.add(key)
            continue
        a = gt[key]
        if key == "object_ids" and a.ndim == 1:
            count = a.shape[0]
        d = a.shape[0] if key == "D" and a.ndim == 1 and a.shape[0] in DISTORTION_LENGTHS else None
        want = spec.expected_shape(height, width, count if count is not None else a.shape[0] if a.ndim else None, d)
        if str(a.dtype) != spec.dtype:
            issues.append(f"{key} is {a.dtype}, not {spec.dtype}")
            if not np.issubdtype(a.dtype, np.number):
                bad.add(key)
        if a.shape != want:
            issues.append(f"{key} has shape {a.shape}, not {want}")
            bad.add(key)
    return KeyCheck(tuple(issues), frozenset(bad))


@dataclass(eq=False)
class EyeFrame:
    """One eye of one frame as the checks see it (see the module docstring).

    ``gt`` is None when the file is missing or unreadable (``load_error`` says which); the ``schema`` check
    reports that, and other checks only ever see usable frames (:attr:`usable`).
    """

    run: VerifyRun
    eye: str
    index: int
    gt: dict[str, np.ndarray] | None
    load_error: str = ""
    errors: FrameErrors | None = None  # per-pixel error maps, kept when error-map pictures are drawn

    # -- reporting --
    def add(self, check: str, metric: str, value: float | None, tol: float | None, **settings) -> None:
        """One value of a metric for this eye and frame (``settings``: see :meth:`Collector.metric`)."""
        self.run.collector.add(check, self.eye, metric, self.index, value, tol, **settings)

    def problem(self, text: str) -> None:
        self.run.problems.append(f"frame {self.index:06d} {self.eye}: {text}")

    # -- the file --
    @property
    def paths(self) -> FramePaths:
        return frame_paths(self.run.dataset.root, self.eye, self.index)

    @cached_property
    def key_check(self) -> KeyCheck:
        return check_keys(self.gt or {}, *self.run.shape, rectified=self.run.rectified)

    @property
    def usable(self) -> bool:
        """Readable, with depth, K and T_world_cam of the right shape."""
        return self.gt is not None and not self.key_check.bad_keys & set(CORE_KEYS)

    def map(self, key: str) -> np.ndarray | None:
        """A per-pixel map of the schema if present with its schema shape, else None."""
        a = (self.gt or {}).get(key)
        return a if a is not None and a.shape == SCHEMA[key].expected_shape(*self.run.shape) else None

    # -- derived arrays (usable frames) --
    @property
    def K(self) -> np.ndarray:
        return self.gt["K"]

    @property
    def T_world_cam(self) -> np.ndarray:
        return self.gt["T_world_cam"]

    @cached_property
    def camera(self) -> Camera:
        """This eye's camera: the npz's K and D (none: a pinhole) at the dataset's image size."""
        height, width = self.run.shape
        D = self.gt.get("D")
        return Camera.from_K(self.K, width, height, () if D is None else np.asarray(D, dtype=np.float64))

    @cached_property
    def depth(self) -> np.ndarray:
        """Planar depth, float64."""
        return self.gt["depth"].astype(np.float64)

    @cached_property
    def surface(self) -> np.ndarray:
        return surface_mask(self.depth)

    @cached_property
    def segmentation(self) -> np.ndarray:
        """Instance ids (zeros when the map is absent)."""
        seg = self.map("segmentation")
        return seg if seg is not None else np.zeros(self.run.shape, np.uint16)

    @cached_property
    def static(self) -> np.ndarray:
        """Pixels not showing a moving object."""
        if not self.run.moving:
            return np.ones(self.run.shape, bool)
        return ~np.isin(self.segmentation, list(self.run.moving))

    @cached_property
    def rays(self) -> np.ndarray:
        """Camera-frame rays (unit z) through every pixel centre, of this eye's camera (NaN: no ray)."""
        return self.camera.rays()

    # -- the oracle --
    @cached_property
    def oracle_pixels(self) -> np.ndarray:
        """Pixels whose surface the oracle models (all False without an oracle)."""
        if self.run.oracle is None:
            return np.zeros(self.run.shape, bool)
        return self.run.oracle.covers(self.index, self.segmentation)

    @cached_property
    def cast(self) -> RayCast:
        """The oracle's ray cast of this eye at this frame (only for checks that need the oracle)."""
        return self.run.oracle.cast(self.index, self.camera, self.T_world_cam)

    def moved_points(self, other: int) -> np.ndarray | None:
        """World positions at frame ``other`` of the surface points under each pixel, when the oracle follows
        moving surfaces (:meth:`~rgbd2scene.verify.oracle.ModelOracle.moved_points`); else None."""
        follow = getattr(self.run.oracle, "moved_points", None)
        if follow is None:
            return None
        return follow(self.index, other, self.camera, self.T_world_cam)

    # -- other frames of this eye --
    def pose(self, index: int) -> np.ndarray | None:
        return self.run.poses.get((self.eye, index))

    def depth_at(self, index: int) -> np.ndarray | None:
        return self.run.depth(self.eye, index)


@dataclass(eq=False)
class PairFrame:
    """Both (usable) eyes of one frame."""

    left: EyeFrame
    right: EyeFrame

    @property
    def run(self) -> VerifyRun:
        return self.left.run

    @property
    def index(self) -> int:
        return self.left.index

    def add(self, check: str, eye: str, metric: str, value: float | None, tol: float | None, **settings) -> None:
        """One value of a metric of this frame; ``eye`` labels the row ("both", "L->R", ...)."""
        self.run.collector.add(check, eye, metric, self.index, value, tol, **settings)


class Check:
    """Base of a check: subclass it in a module of ``verify/checks/`` and list an instance in ``checks.CHECKS``.

    Class attributes
    ----------------
    names : the check names its report rows use, in report order (usually one).
    maps : the schema keys it reads; the driver calls it only for frames with at least one of them.
    needs_oracle : compares with the scene oracle; without one its rows are "skip" with the reason.
    checks_broken_files : also called for frames that are missing, unreadable or lack depth, K or pose.
    """

    names: ClassVar[tuple[str, ...]] = ()
    maps: ClassVar[tuple[str, ...]] = ()
    needs_oracle: ClassVar[bool] = False
    checks_broken_files: ClassVar[bool] = False

    def declare(self, run: VerifyRun) -> None:
        """Declare the headline metrics (``run.collector.metric(...)``), reported as skip if they never get a value."""

    def check_eye(self, frame: EyeFrame) -> None:
        """Check one eye of one frame."""

    def check_pair(self, pair: PairFrame) -> None:
        """Check both eyes of one frame together."""

    def applies_to(self, frame: EyeFrame) -> bool:
        """Whether the driver calls this check for ``frame`` (see the class attributes)."""
        if not frame.usable:
            return self.checks_broken_files
        return self.checks_broken_files or any(frame.map(key) is not None for key in self.maps)
