"""Stereo methods behind one interface: ``method(index, left, right) -> left disparity`` (float32 pixels, NaN
where the method gives none).

- :class:`Sgbm`: OpenCV's semi-global block matching, tuned for small-baseline endoscope pairs.
- :class:`Elas`: ELAS (Geiger et al. 2010; PyPI ``pyelas``, module ``elas``), the best method of the
  VisionBlender paper's comparison.
- :class:`PredictionFolder`: any external method's maps, one ``NNNNNN.npy`` (float32 pixels) or ``NNNNNN.pfm``
  per frame, so learned networks can be compared.
- :class:`GroundTruthDisparity`: the dataset's own disparity (a sanity row: zero error, density 1).

Built-in methods search the disparity range of :class:`DisparityRange`, by default the dataset's ground-truth
depth range widened by 10 % (like an endoscope's known working distance): ``d = fx·B/z``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from rgbd2scene.dataset.layout import frame_name
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError
from rgbd2scene.files.flowio import read_pfm

BUILTIN = ("sgbm", "elas", "gt")
RANGE_MARGIN = 0.1
#: ELAS stores disparities in 8 bits
ELAS_MAX_DISPARITY = 255


class StereoMethod(Protocol):
    name: str

    def __call__(self, index: int, left: np.ndarray, right: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class DisparityRange:
    """Disparities searched, in pixels: ``low`` (farthest depth) to ``high`` (nearest)."""

    low: float
    high: float

    @classmethod
    def from_depths(cls, z_min: float, z_max: float, fx: float, baseline: float,
                    margin: float = RANGE_MARGIN) -> DisparityRange:
        """The range that covers depths [z_min, z_max] (metres) widened by ``margin`` on both sides."""
        if not (0 < z_min <= z_max and math.isfinite(z_max)):
            raise ValueError(f"depth range must satisfy 0 < min <= max, got {z_min}, {z_max}")
        return cls(fx * baseline / (z_max * (1 + margin)), fx * baseline / (z_min * (1 - margin)))

    @property
    def middle(self) -> float:
        return 0.5 * (self.low + self.high)


def dataset_depth_range(dataset: Dataset) -> tuple[float, float]:
    """Nearest and farthest ground-truth depth (metres) over the left eye of every frame."""
    lo, hi = math.inf, 0.0
    for index in dataset.frame_indices():
        z = dataset.gt("left", index, ("depth",))["depth"]
        z = z[np.isfinite(z)]
        if z.size:
            lo, hi = min(lo, float(z.min())), max(hi, float(z.max()))
    if not hi > 0:
        raise UserError(f"{dataset.root}: no valid ground-truth depth to score against")
    return lo, hi


def _gray(rgb: np.ndarray) -> np.ndarray:
    import cv2

    return np.ascontiguousarray(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


@dataclass
class Sgbm:
    """OpenCV StereoSGBM (3-way mode). ``block`` 5 px keeps fine tissue texture at endoscope resolutions;
    P1/P2 follow OpenCV's recommended 8·3·block² / 32·3·block²; the disparity search covers ``range`` (rounded
    out to a multiple of 16 as SGBM requires); uniqueness 5 %, speckles up to 100 px filtered, left/right check
    1 px. Output in 1/16 px; SGBM's invalid marker becomes NaN."""

    range: DisparityRange
    block: int = 5
    name: str = "sgbm"

    def __post_init__(self):
        import cv2

        self.min_disparity = max(0, int(math.floor(self.range.low)))
        count = int(math.ceil(self.range.high)) + 1 - self.min_disparity
        self.num_disparities = 16 * max(1, math.ceil(count / 16))
        self.matcher = cv2.StereoSGBM_create(
            minDisparity=self.min_disparity, numDisparities=self.num_disparities, blockSize=self.block,
            P1=8 * 3 * self.block**2, P2=32 * 3 * self.block**2, disp12MaxDiff=1, uniquenessRatio=5,
            speckleWindowSize=100, speckleRange=2, preFilterCap=63, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)

    def __call__(self, index: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        raw = self.matcher.compute(left, right)
        d = raw.astype(np.float32) / 16.0
        d[raw < self.min_disparity * 16] = np.nan
        return d


@dataclass
class Elas:
    """ELAS with libelas' ROBOTICS preset (its default: no gap interpolation, so it stays honest about what it
    could not match), searching 0 to the top of ``range`` (at most 255 px, ELAS' limit). The search starts at 0
    because with a band that excludes it libelas found no support points on test pairs and returned zeros.
    Invalid pixels (-10) become NaN."""

    range: DisparityRange
    name: str = "elas"

    def __post_init__(self):
        try:
            import elas
        except ImportError:
            raise UserError("ELAS is not installed (PyPI 'pyelas': 'make install' builds it; or leave it out "
                            "with --methods sgbm)") from None
        self.matcher = elas.Elas()
        self.matcher.set_preset(elas.PRESET_ROBOTICS)
        self.matcher.disp_min = 0
        self.matcher.disp_max = min(ELAS_MAX_DISPARITY, int(math.ceil(self.range.high)))

    def __call__(self, index: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        d, _ = self.matcher.process(_gray(left), _gray(right))
        d = np.asarray(d, np.float32).copy()
        d[d < 0] = np.nan
        return d


@dataclass
class PredictionFolder:
    """Left disparity maps of an external method: ``folder/NNNNNN.npy`` (float32 pixels) or ``NNNNNN.pfm``; for a
    raw dataset, in the rectified grid the built-in methods match in (:mod:`rgbd2scene.evaluate.grid`).

    Non-finite and non-positive values are invalid predictions. A missing or unreadable file, or one of the
    wrong size, is an error naming the file (a frame is never silently skipped)."""

    folder: Path
    shape: tuple[int, int]
    name: str = ""

    def __post_init__(self):
        self.folder = Path(self.folder)
        self.name = self.name or self.folder.name
        if not self.folder.is_dir():
            raise UserError(f"{self.folder}: predictions folder not found")

    def path(self, index: int) -> Path:
        stem = frame_name(index)
        for suffix in (".npy", ".pfm"):
            candidate = self.folder / f"{stem}{suffix}"
            if candidate.is_file():
                return candidate
        raise UserError(f"{self.folder / stem}.npy: no prediction for frame {index} (.npy or .pfm)")

    def __call__(self, index: int, left: np.ndarray | None = None, right: np.ndarray | None = None) -> np.ndarray:
        path = self.path(index)
        if path.suffix == ".npy":
            try:
                d = np.load(path, allow_pickle=False)
            except (OSError, ValueError) as exc:
                raise UserError(f"{path}: unreadable prediction ({exc})") from None
        else:
            d = read_pfm(path)
            if d is None:
                raise UserError(f"{path}: unreadable PFM file")
        d = np.asarray(d)
        if d.ndim == 3 and d.shape[2] == 1:
            d = d[..., 0]
        if d.shape != self.shape or not np.issubdtype(d.dtype, np.number):
            raise UserError(f"{path}: prediction must be a number array of shape {self.shape} (H, W), "
                            f"got {d.dtype} {d.shape}")
        return d.astype(np.float32)


@dataclass
class GroundTruthDisparity:
    """The dataset's left ground-truth disparity as a 'method' (sanity check of the scoring)."""

    dataset: Dataset
    name: str = "gt"

    def __call__(self, index: int, left: np.ndarray | None = None, right: np.ndarray | None = None) -> np.ndarray:
        return self.dataset.gt("left", index, ("disparity",))["disparity"]


def parse_prediction_arg(text: str) -> tuple[str, Path]:
    """``DIR`` or ``NAME=DIR`` -> (name, folder); the name defaults to the folder's name."""
    name, sep, folder = text.partition("=")
    if not sep:
        return Path(text).name, Path(text)
    return name, Path(folder)


def build_methods(dataset: Dataset, names: list[str], predictions: list[str] = (),
                  disparity_range: DisparityRange | None = None) -> list[StereoMethod]:
    """The methods ``names`` (of :data:`BUILTIN`) and one per predictions folder, for one dataset."""
    unknown = [n for n in names if n not in BUILTIN]
    if unknown:
        raise ValueError(f"unknown method {', '.join(unknown)} (choose from {', '.join(BUILTIN)})")
    if disparity_range is None and {"sgbm", "elas"} & set(names):
        disparity_range = DisparityRange.from_depths(*dataset_depth_range(dataset), dataset.fx, dataset.baseline)
    makers = {"sgbm": lambda: Sgbm(disparity_range), "elas": lambda: Elas(disparity_range),
              "gt": lambda: GroundTruthDisparity(dataset)}
    methods: list[StereoMethod] = [makers[n]() for n in names]
    for text in predictions:
        name, folder = parse_prediction_arg(text)
        methods.append(PredictionFolder(folder, (dataset.height, dataset.width), name))
    return methods
