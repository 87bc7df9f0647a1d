"""``rgbd2scene realism``: a rendered frame of a dataset against a real frame (or stereo pair) of a scope.

Each measure of :mod:`rgbd2scene.realism.measures` is taken on the real and the rendered image of each eye,
over the same pixels (the real frame's mask, when given), and reported with the ratio render / real; with a
right image, so is the stereo difficulty of both pairs (:mod:`rgbd2scene.realism.stereo`). A ratio within its
goal band (:data:`IMAGE_BAND`, :data:`STEREO_BAND`, issue 15) counts as close.

Which pixels: a mask image (``--real-mask``) keeps the pixels at least half its full scale (for a 0/1 image:
the non-zero ones); with ``--surface-only`` only the pixels where the rendered eye sees a surface count (a
twin's mesh rarely covers the whole view: the rest of the render is empty background).

Stereo: a raw dataset (``"camera": {"rectified": false}``) is rectified with its ``calibration.yaml`` before
matching; the real pair with ``--real-calib`` when given (a calibration JSON or Hamlyn-style folder), else with
the dataset's calibration when the dataset is raw (a twin's rig), else it is taken as rectified. The
disparities searched cover the rendered frame's ground-truth depth range widened by 10 %
(:class:`~rgbd2scene.evaluate.methods.DisparityRange`), converted to each pair's own focal length x baseline,
since a twin sees the same scene as the real scope.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from rgbd2scene.capture.stereo import read_stereo_calibration
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError
from rgbd2scene.evaluate.methods import DisparityRange, Elas, Sgbm
from rgbd2scene.files.flowio import read_pfm
from rgbd2scene.files.images import read_image
from rgbd2scene.geometry.stereo import StereoCalibration
from rgbd2scene.realism import measures as m
from rgbd2scene.realism import stereo

#: Goal bands of render / real (issue 15): image statistics, stereo difficulty.
IMAGE_BAND = (0.8, 1.25)
STEREO_BAND = (0.85, 1.2)
METHODS = ("sgbm", "elas")


@dataclass(frozen=True)
class Measure:
    """One image statistic: its name, unit (for the table) and function of (rgb, mask)."""

    name: str
    unit: str
    fn: Callable[[np.ndarray, np.ndarray | None], float]


IMAGE_MEASURES = (
    Measure("brightness", "luma 0-255", m.brightness),
    Measure("contrast", "std / mean", m.rms_contrast),
    Measure("chromaticity r", "share", lambda rgb, mask: float(m.chromaticity(rgb, mask)[0])),
    Measure("chromaticity g", "share", lambda rgb, mask: float(m.chromaticity(rgb, mask)[1])),
    Measure("chromaticity b", "share", lambda rgb, mask: float(m.chromaticity(rgb, mask)[2])),
    Measure("saturation", "HSV 0-1", m.mean_saturation),
    Measure("noise sigma", "luma levels", m.noise_sigma),
    Measure("high-frequency share", f"power >= {m.HIGH_FREQUENCY} c/px", m.high_frequency_share),
    Measure("gradient mean", "contrast / px", m.gradient_mean),
    Measure("highlight share", "pixels", m.highlight_share),
)


@dataclass(frozen=True)
class Row:
    """One line of the table: a measure of one eye (or pair), real and rendered, and their ratio."""

    measure: str
    eye: str
    unit: str
    real: float
    render: float
    band: tuple[float, float]

    @property
    def ratio(self) -> float:
        """render / real; 1 when both are 0, inf when only the real one is."""
        if self.real == 0:
            return 1.0 if self.render == 0 else math.inf
        return self.render / self.real

    @property
    def within(self) -> bool:
        return self.band[0] <= self.ratio <= self.band[1]

    def to_dict(self) -> dict:
        ratio = self.ratio
        return {**asdict(self), "band": list(self.band), "ratio": ratio if math.isfinite(ratio) else None,
                "within": self.within}


@dataclass
class RealismReport:
    """The comparison of one dataset frame with a real frame or pair."""

    dataset: str
    frame: int
    real: dict[str, str]
    rows: list[Row] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def misses(self) -> list[Row]:
        return [r for r in self.rows if not r.within]

    def to_dict(self) -> dict:
        return {"dataset": self.dataset, "frame": self.frame, "real": self.real,
                "bands": {"image": list(IMAGE_BAND), "stereo": list(STEREO_BAND)},
                "rows": [r.to_dict() for r in self.rows], "misses": len(self.misses), "notes": self.notes}


@dataclass
class Inputs:
    """What the comparison reads, already checked: images RGB uint8, the mask bool (H, W) or None."""

    dataset: Dataset
    frame: int
    real: dict[str, np.ndarray]  # eye -> real image
    render: dict[str, np.ndarray]  # eye -> rendered image
    mask: np.ndarray | None
    surface: dict[str, np.ndarray] | None  # eye -> rendered pixels that see a surface (--surface-only)
    real_disparity: np.ndarray | None
    real_calib: StereoCalibration | None  # of the real pair, when it is raw
    paths: dict[str, str]

    def eye_mask(self, eye: str) -> np.ndarray | None:
        """The pixels measured in this eye: the real frame's mask, and with ``surface`` the rendered surface."""
        if self.surface is None:
            return self.mask
        return self.surface[eye] if self.mask is None else self.mask & self.surface[eye]


# ----------------------------------------------------------------------------------------------------- reading


def _read_rgb(path: str | Path, what: str) -> np.ndarray:
    if not Path(path).is_file():
        raise UserError(f"{path}: {what} not found")
    image = read_image(path)
    if image is None:
        raise UserError(f"{path}: {what} is not a readable image")
    return image


def read_mask(path: str | Path) -> np.ndarray:
    """A mask image as bool (H, W): pixels at least half its full scale, or non-zero in a 0/1 image."""
    if not Path(path).is_file():
        raise UserError(f"{path}: mask not found")
    grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if grey is None:
        raise UserError(f"{path}: mask is not a readable image")
    mask = grey >= 128 if grey.max() > 1 else grey > 0
    if not mask.any():
        raise UserError(f"{path}: the mask keeps no pixel")
    return mask


def read_disparity(path: str | Path) -> np.ndarray:
    """A left disparity map, float pixels (``.npy`` or ``.pfm``); non-finite or non-positive values unknown."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: disparity file not found")
    try:
        d = np.load(path, allow_pickle=False) if path.suffix == ".npy" else read_pfm(path)
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: unreadable disparity ({exc})") from None
    if d is None:
        raise UserError(f"{path}: unreadable disparity (give .npy or .pfm)")
    d = np.asarray(d)
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[..., 0]
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.number):
        raise UserError(f"{path}: disparity must be a number array (H, W), got {d.dtype} {d.shape}")
    d = d.astype(np.float64)
    with np.errstate(invalid="ignore"):
        d[~(d > 0)] = np.nan
    return d


def _check_size(path: str | Path, shape: tuple[int, ...], dataset: Dataset, what: str) -> None:
    if tuple(shape[:2]) != (dataset.height, dataset.width):
        raise UserError(f"{path}: the {what} is {shape[1]}x{shape[0]} but the dataset {dataset.root} is "
                        f"{dataset.width}x{dataset.height} (render the dataset at the real frame's size, "
                        f"e.g. render --size {shape[1]}x{shape[0]})")


def load_inputs(dataset_dir: str | Path, left: str | Path, right: str | Path | None = None, frame: int = 0,
                mask: str | Path | None = None, real_disparity: str | Path | None = None,
                real_calib: str | Path | None = None, surface_only: bool = False) -> Inputs:
    """Read and check everything (one-line :class:`UserError` naming the file on any problem) before anything
    is computed or written."""
    dataset = Dataset(dataset_dir)
    if not 0 <= frame < dataset.frames or not (Path(dataset.rgb_file("left", frame)).is_file()):
        raise UserError(f"{dataset.root}: no rendered frame {frame} (the dataset has {dataset.frames} frames)")
    if real_disparity is not None and right is None:
        raise UserError("realism: --real-disparity needs the right image (stereo difficulty)")
    if real_calib is not None and right is None:
        raise UserError("realism: --real-calib needs the right image (stereo difficulty)")
    paths = {"left": str(left)}
    real = {"left": _read_rgb(left, "real left image")}
    if right is not None:
        paths["right"] = str(right)
        real["right"] = _read_rgb(right, "real right image")
    for eye, image in real.items():
        _check_size(paths[eye], image.shape, dataset, "real frame")
    render = {eye: dataset.rgb(eye, frame) for eye in real}
    valid = None
    if mask is not None:
        valid = read_mask(mask)
        _check_size(mask, valid.shape, dataset, "mask")
        paths["mask"] = str(mask)
    disparity = None
    if real_disparity is not None:
        disparity = read_disparity(real_disparity)
        _check_size(real_disparity, disparity.shape, dataset, "real disparity")
        paths["disparity"] = str(real_disparity)
    calib = None
    if real_calib is not None:
        try:
            calib = read_stereo_calibration(real_calib, image_size=(dataset.width, dataset.height))
        except (OSError, ValueError) as exc:
            raise UserError(f"{real_calib}: bad stereo calibration: {exc}") from None
        if calib.size != (dataset.width, dataset.height):
            raise UserError(f"{real_calib}: the calibration is for {calib.width}x{calib.height} but the dataset is "
                            f"{dataset.width}x{dataset.height}")
        paths["calibration"] = str(real_calib)
    surface = None
    if surface_only:
        surface = {eye: np.isfinite(dataset.gt(eye, frame, ("depth",))["depth"]) for eye in real}
        for eye, seen in surface.items():
            if not (seen if valid is None else seen & valid).any():
                raise UserError(f"{dataset.root}: frame {frame} ({eye}) shows no surface inside the mask")
    return Inputs(dataset, frame, real, render, valid, surface, disparity, calib, paths)


# ----------------------------------------------------------------------------------------------------- measuring


def image_rows(inputs: Inputs) -> list[Row]:
    """Every image measure of each eye, real and rendered over the same pixels."""
    rows = []
    for measure in IMAGE_MEASURES:
        for eye in inputs.real:
            mask = inputs.eye_mask(eye)
            rows.append(Row(measure.name, eye, measure.unit, measure.fn(inputs.real[eye], mask),
                            measure.fn(inputs.render[eye], mask), IMAGE_BAND))
    return rows


def dataset_calibration(dataset: Dataset) -> StereoCalibration | None:
    """The calibration of a raw dataset (``"camera": {"rectified": false}``), None for a rectified one."""
    camera = dataset.meta.get("camera") or {}
    if not (isinstance(camera, dict) and camera.get("rectified") is False):
        return None
    try:
        return read_stereo_calibration(dataset.root / "calibration.yaml")
    except (OSError, ValueError) as exc:
        raise UserError(f"{dataset.root / 'calibration.yaml'}: raw dataset without a usable calibration ({exc})") \
            from None


def _rendered_pair(inputs: Inputs, calib: StereoCalibration | None
                   ) -> tuple[stereo.RectifiedView, np.ndarray | None, list[str]]:
    """The rendered pair ready for matching, its ground-truth disparity (None for a raw dataset) and notes."""
    ds = inputs.dataset
    left, right = inputs.render["left"], inputs.render["right"]
    mask = inputs.eye_mask("left")
    mask = np.ones(left.shape[:2], bool) if mask is None else mask
    if calib is not None:
        return (stereo.rectify_with(calib, left, right, mask), None,
                ["raw dataset: rectified with its calibration.yaml for matching; no ground-truth disparity in that "
                 "grid, so the stereo error rows are left out"])
    gt = ds.gt("left", inputs.frame, optional=("disparity",))
    return stereo.RectifiedView(left, right, mask, ds.fx * ds.baseline), gt.get("disparity"), []


def _depth_range(inputs: Inputs) -> tuple[float, float]:
    z = inputs.dataset.gt("left", inputs.frame, ("depth",))["depth"]
    z = z[np.isfinite(z) & (z > 0)]
    if not z.size:
        raise UserError(f"{inputs.dataset.root}: frame {inputs.frame} has no ground-truth depth (needed for the "
                        "disparity range)")
    return float(z.min()), float(z.max())


def stereo_rows(inputs: Inputs, methods: tuple[str, ...] = METHODS) -> tuple[list[Row], list[str]]:
    """Stereo difficulty of the real and the rendered pair (:mod:`rgbd2scene.realism.stereo`)."""
    dataset_calib = dataset_calibration(inputs.dataset)
    rendered, rendered_gt, notes = _rendered_pair(inputs, dataset_calib)
    real_mask = inputs.eye_mask("left")
    real_mask = np.ones(inputs.real["left"].shape[:2], bool) if real_mask is None else real_mask
    real_calib = inputs.real_calib if inputs.real_calib is not None else dataset_calib
    if real_calib is not None:
        real = stereo.rectify_with(real_calib, inputs.real["left"], inputs.real["right"], real_mask)
        notes.append("real pair rectified with " + ("--real-calib" if inputs.real_calib is not None else
                                                    "the dataset's calibration.yaml (a twin's rig)") + " for matching")
    else:
        real = stereo.RectifiedView(inputs.real["left"], inputs.real["right"], real_mask, rendered.focal_baseline)
    z_min, z_max = _depth_range(inputs)
    base = DisparityRange.from_depths(z_min, z_max, 1.0, rendered.focal_baseline)
    makers = {"sgbm": Sgbm, "elas": Elas}
    rows = []
    gt_known = rendered_gt is not None and inputs.real_disparity is not None
    if inputs.real_disparity is not None and rendered_gt is None:
        notes.append("--real-disparity given but the dataset has no disparity: stereo error rows left out")
    for name in methods:
        scores = {}
        for side, view, gt in (("real", real, inputs.real_disparity), ("render", rendered, rendered_gt)):
            method = makers[name](stereo.scaled_range(base, view.focal_baseline / rendered.focal_baseline))
            scores[side] = stereo.score_pair(method, view.left, view.right, view.mask, gt if gt_known else None)
        label = name.upper()
        fields = [("density", "share of pixels", "density"), ("LR consistency", "share of matches", "lr_consistency")]
        if gt_known:
            fields += [("EPE", "px", "epe"), ("bad-2", "share > 2 px", "bad2")]
        for title, unit, attr in fields:
            rows.append(Row(f"{label} {title}", "pair", unit, getattr(scores["real"], attr),
                            getattr(scores["render"], attr), STEREO_BAND))
    return rows, notes


def compare(inputs: Inputs, methods: tuple[str, ...] = METHODS) -> RealismReport:
    """The full comparison (image rows per eye, then stereo rows when a right image is given)."""
    report = RealismReport(str(inputs.dataset.root), inputs.frame, dict(inputs.paths))
    report.rows = image_rows(inputs)
    if "right" in inputs.real and methods:
        rows, notes = stereo_rows(inputs, methods)
        report.rows += rows
        report.notes += notes
    return report


# ----------------------------------------------------------------------------------------------------- table


def _fmt(value: float) -> str:
    if not math.isfinite(value):
        return "inf" if value > 0 else "n/a"
    return f"{value:.4g}"


def markdown_table(report: RealismReport) -> str:
    """The rows as a Markdown table: measure, eye, unit, real, render, render/real, goal band, close or not."""
    lines = ["| measure | eye | unit | real | render | render / real | goal | |", "|---|---|---|---|---|---|---|---|"]
    for r in report.rows:
        lines.append(f"| {r.measure} | {r.eye} | {r.unit} | {_fmt(r.real)} | {_fmt(r.render)} | {_fmt(r.ratio)} | "
                     f"{r.band[0]:g}-{r.band[1]:g} | {'ok' if r.within else 'MISS'} |")
    return "\n".join(lines)


def summary_line(report: RealismReport) -> str:
    missed = report.misses
    return (f"{len(report.rows) - len(missed)} of {len(report.rows)} figures within their goal band"
            + (": misses " + ", ".join(f"{r.measure} ({r.eye}) {_fmt(r.ratio)}" for r in missed) if missed else ""))


def markdown_report(report: RealismReport) -> str:
    head = [f"# Realism: {report.dataset}, frame {report.frame}", "",
            "Real: " + ", ".join(f"{k} `{v}`" for k, v in report.real.items()) + ".", "",
            "Ratio render / real; goal bands from issue 15 (image statistics "
            f"{IMAGE_BAND[0]}-{IMAGE_BAND[1]}, stereo difficulty {STEREO_BAND[0]}-{STEREO_BAND[1]}).", ""]
    tail = ["", summary_line(report) + "."] + [f"- note: {n}" for n in report.notes]
    return "\n".join(head + [markdown_table(report)] + tail) + "\n"
