"""KITTI 2015-style export: 16-bit PNG disparity and flow as the KITTI devkit reads them.

Layout (frame ``i`` of the dataset is KITTI "scene" ``NNNNNN`` = ``i`` in six digits)::

    OUT/image_2/NNNNNN_10.png          left image of frame i (the dataset's PNG, byte for byte)
    OUT/image_3/NNNNNN_10.png          right image of frame i
    OUT/image_2/NNNNNN_11.png          left image of frame i+1 (the second image of a flow pair)
    OUT/image_3/NNNNNN_11.png          right image of frame i+1
    OUT/disp_occ_0/NNNNNN_10.png       left disparity of frame i
    OUT/flow_occ/NNNNNN_10.png         left forward flow i -> i+1, every pixel with a surface
    OUT/flow_noc/NNNNNN_10.png         the same without the pixels hidden in frame i+1 (datasets with
                                       ``occluded_forward``)
    OUT/calib_cam_to_cam/NNNNNN.txt    S_rect/R_rect/P_rect of cameras 02 (left) and 03 (right)

The last frame (and any frame whose successor is missing) has no ``_11`` images and no flow.

Conventions and how they differ from the dataset's (CONVENTIONS §1-§3):

- Disparity: uint16 = round(d·256), 0 = invalid (the dataset's NaN). Values of 256 px and more do not fit
  (65535/256 = 255.996) and are written as invalid; the summary counts them.
- Flow: 3-channel uint16 PNG whose channels, in the PNG's own R, G, B order, are u·64 + 2^15, v·64 + 2^15 and
  valid (1/0), as the devkit's ``io_flow.h`` writes them (OpenCV's ``imread`` returns them as B, G, R, so a
  reader flips the channels). u, v are the dataset's forward flow (same sign: p(t+1) = p(t) + flow). Values
  beyond ±512 px do not fit and are written as invalid. Rounding makes the stored values exact to 1/128 px
  (flow) and 1/512 px (disparity).
- ``P_rect_03[0, 3]`` = -fx·B: camera 02 (left) is the reference, as in the dataset.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgbd2scene.dataset.layout import frame_name
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.export.common import ExportSummary, complete_frames, frame_indices, require_keys
from rgbd2scene.files.atomic import write_bytes, write_text
from rgbd2scene.files.images import write_image

DISPARITY_SCALE = 256.0
#: The left eye's maps every exported frame needs.
GT_KEYS = ("disparity", "flow_forward")
FLOW_SCALE = 64.0
FLOW_OFFSET = 2.0**15
IMAGE_DIRS = {"left": "image_2", "right": "image_3"}


def encode_disparity(disparity: np.ndarray) -> np.ndarray:
    """KITTI disparity PNG values: uint16 round(d·256), 0 where d is NaN, not positive or too large to store."""
    d = np.asarray(disparity, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        scaled = np.round(d * DISPARITY_SCALE)
        valid = np.isfinite(scaled) & (scaled >= 1) & (scaled <= 65535)
    return np.where(valid, scaled, 0).astype(np.uint16)


def encode_flow(flow: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """KITTI flow PNG values (H, W, 3) uint16 in the PNG's R, G, B order: u·64 + 2^15, v·64 + 2^15, valid.

    A pixel is valid where both components are finite, fit the 16 bits and ``valid`` (if given) is True.
    """
    f = np.asarray(flow, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        scaled = np.round(f * FLOW_SCALE + FLOW_OFFSET)
        ok = (np.isfinite(scaled) & (scaled >= 0) & (scaled <= 65535)).all(axis=-1)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    out = np.zeros((*f.shape[:2], 3), np.uint16)
    out[..., :2] = np.where(ok[..., None], scaled, FLOW_OFFSET)
    out[..., 2] = ok
    return out


def calib_text(K: np.ndarray, baseline: float, width: int, height: int) -> str:
    """calib_cam_to_cam.txt lines of the rectified pair (cameras 02 = left, 03 = right)."""
    P2 = np.hstack([K, np.zeros((3, 1))])
    P3 = P2.copy()
    P3[0, 3] = -K[0, 0] * baseline

    def row(values) -> str:
        return " ".join(f"{v:.12e}" for v in np.ravel(values))

    lines = []
    for cam, P in (("02", P2), ("03", P3)):
        lines += [f"S_rect_{cam}: {row([width, height])}", f"R_rect_{cam}: {row(np.eye(3))}", f"P_rect_{cam}: {row(P)}"]
    return "\n".join(lines) + "\n"


def export_kitti(dataset: Dataset, out: str | Path, progress: bool = True) -> ExportSummary:
    """Write the KITTI-style folder (see the module docstring) frame by frame."""
    out = Path(out)
    summary = ExportSummary("kitti", out)
    require_keys(dataset, ("left",), GT_KEYS)
    complete = set(complete_frames(dataset))
    calib = calib_text(dataset.K, dataset.baseline, dataset.width, dataset.height)
    too_far = 0
    for index in frame_indices(dataset, progress, "export kitti"):
        name = frame_name(index)
        for eye, folder in IMAGE_DIRS.items():
            data = dataset.rgb_file(eye, index).read_bytes()
            write_bytes(out / folder / f"{name}_10.png", data)
            summary.files += 1
            if index - 1 in complete:
                write_bytes(out / folder / f"{frame_name(index - 1)}_11.png", data)
                summary.files += 1
        gt = dataset.gt("left", index, GT_KEYS, optional=("occluded_forward",))
        disparity = encode_disparity(gt["disparity"])
        too_far += int((np.isfinite(gt["disparity"]) & (disparity == 0)).sum())
        write_image(out / "disp_occ_0" / f"{name}_10.png", disparity)
        write_text(out / "calib_cam_to_cam" / f"{name}.txt", calib)
        summary.files += 2
        if index + 1 in complete:
            write_image(out / "flow_occ" / f"{name}_10.png", encode_flow(gt["flow_forward"]))
            summary.files += 1
            if "occluded_forward" in gt:
                write_image(out / "flow_noc" / f"{name}_10.png",
                            encode_flow(gt["flow_forward"], ~gt["occluded_forward"]))
                summary.files += 1
        summary.frames += 1
    if too_far:
        summary.notes.append(f"{too_far} disparity values of 256 px or more written as invalid (KITTI's 16 bits)")
    return summary
