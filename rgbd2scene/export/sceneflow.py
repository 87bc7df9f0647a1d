"""SceneFlow-style export (FlyingThings3D / Monkaa / Driving layout of one sequence): PFM disparity, Middlebury
``.flo`` flow.

Layout (``NNNNNN`` = the dataset's frame number)::

    OUT/frames_cleanpass/left/NNNNNN.png            the dataset's PNGs, byte for byte (and right/)
    OUT/disparity/left/NNNNNN.pfm                   disparity of each eye (and right/)
    OUT/optical_flow/into_future/left/NNNNNN.flo    forward flow t -> t+1 (not on the last frame; and right/)
    OUT/optical_flow/into_past/left/NNNNNN.flo      backward flow t -> t-1 (not on the first frame; and right/)

Conventions and how they differ from the dataset's and from the original SceneFlow files:

- Disparity: float32 PFM (little-endian, rows bottom to top, as the format fixes), positive in pixels for
  both eyes like SceneFlow's; NaN where there is no surface (SceneFlow itself has no invalid pixels, so its
  loaders do not mask; ``d < max_disp`` masks, common in training code, drop NaN).
- Flow: Middlebury ``.flo`` (SceneFlow ships PFM flow; ``.flo`` is what optical-flow loaders read), the
  dataset's (du, dv) with the same signs; where there is no surface it holds 1e10, Middlebury's "unknown
  flow" value (readers treat |u| or |v| > 1e9 as unknown).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgbd2scene.dataset.layout import EYES, frame_name
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.export.common import ExportSummary, complete_frames, frame_indices, require_keys
from rgbd2scene.files.atomic import write_bytes
from rgbd2scene.files.flowio import write_flo, write_pfm

#: Middlebury's value for unknown flow (``UNKNOWN_FLOW`` in its flowIO code; readers test > 1e9)
UNKNOWN_FLOW = 1e10
FLOW_DIRS = {"flow_forward": "into_future", "flow_backward": "into_past"}


def flo_values(flow: np.ndarray) -> np.ndarray:
    """Flow (H, W, 2) for a ``.flo`` file: float32, NaN replaced by Middlebury's unknown-flow value."""
    f = np.asarray(flow, dtype=np.float32)
    return np.where(np.isfinite(f).all(axis=-1, keepdims=True), f, np.float32(UNKNOWN_FLOW))


def export_sceneflow(dataset: Dataset, out: str | Path, progress: bool = True) -> ExportSummary:
    """Write the SceneFlow-style folder (see the module docstring) frame by frame."""
    out = Path(out)
    summary = ExportSummary("sceneflow", out)
    require_keys(dataset, EYES, ("disparity", *FLOW_DIRS))
    complete = set(complete_frames(dataset))
    for index in frame_indices(dataset, progress, "export sceneflow"):
        name = frame_name(index)
        for eye in EYES:
            write_bytes(out / "frames_cleanpass" / eye / f"{name}.png", dataset.rgb_file(eye, index).read_bytes())
            gt = dataset.gt(eye, index, ("disparity", *FLOW_DIRS))
            write_pfm(out / "disparity" / eye / f"{name}.pfm", gt["disparity"])
            summary.files += 2
            for key, folder in FLOW_DIRS.items():
                other = index + 1 if key == "flow_forward" else index - 1
                if other in complete:
                    write_flo(out / "optical_flow" / folder / eye / f"{name}.flo", flo_values(gt[key]))
                    summary.files += 1
        summary.frames += 1
    return summary
