"""``flow_fwd`` / ``flow_bwd``: optical flow against moving each surface point into the next / previous frame.

With the scene model as oracle, the reference follows the surface point under each pixel (moving objects
and deforming tissue too: :meth:`~rgbd2scene.verify.oracle.ModelOracle.moved_points`) and projects it with
the other frame's pose. Otherwise it moves the static scene with the camera only (K and the two poses of
this eye, ``conventions.flow_between_cameras``), and pixels of moving objects are left out. On the last
(forward) and first (backward) frame the flow must be NaN everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.conventions import invert_pose, pixel_grid, transform_points
from rgbd2scene.dataset.layout import EYES
from rgbd2scene.verify.error_maps import ErrorPanel, pixel_states, ratio, worst
from rgbd2scene.verify.framework import Check, EyeFrame, VerifyRun, median_p99
from rgbd2scene.verify.report import fmt


@dataclass(frozen=True)
class Direction:
    key: str  # the map
    check: str  # the report's check name
    step: int  # to the other frame
    boundary: str  # the frame without another one, where the map is all NaN


DIRECTIONS = (Direction("flow_forward", "flow_fwd", 1, "last"), Direction("flow_backward", "flow_bwd", -1, "first"))


class FlowCheck(Check):
    names = tuple(d.check for d in DIRECTIONS)
    maps = tuple(d.key for d in DIRECTIONS)

    def declare(self, run: VerifyRun) -> None:
        if run.dataset.frames > 1:
            for eye in EYES:
                for d in DIRECTIONS:
                    run.collector.metric(d.check, eye, "median endpoint error", run.tol.flow_median_px, unit="px",
                                         note=run.no_pixels_note)

    def check_eye(self, frame: EyeFrame) -> None:
        panels: dict[str, tuple[float, ErrorPanel]] = {}  # direction -> (score, error map)
        for d in DIRECTIONS:
            flow = frame.map(d.key)
            if flow is None:
                continue
            other = frame.index + d.step
            if not 0 <= other <= frame.run.last:
                frame.add(d.check, f"finite values on the {d.boundary} frame (count)",
                          float(np.isfinite(flow).any(axis=-1).sum()), 0.0)
                continue
            T_other = frame.pose(other)
            kept = _compare(frame, d, flow, other, T_other) if T_other is not None else None
            if kept is not None:
                panels[d.key] = kept
        if frame.errors is not None and panels:
            # The picture shows the forward flow unless there is none (last frame) or only the backward flow
            # is out of tolerance; the frame's flow score is the worse of the two directions.
            fwd, bwd = (panels.get(d.key) for d in DIRECTIONS)
            show = fwd if fwd is not None and (bwd is None or not bwd[0] > max(fwd[0], 1.0)) else bwd
            frame.errors.panels["flow"] = show[1]
            frame.errors.scores["flow"] = worst(*(score for score, _ in panels.values()))


def _compare(frame: EyeFrame, d: Direction, flow: np.ndarray, other: int,
             T_other: np.ndarray) -> tuple[float, ErrorPanel] | None:
    """Endpoint errors against the reprojection into frame ``other``; the error map and its score when kept."""
    tol = frame.run.tol
    surface = frame.surface
    moved = frame.moved_points(other)
    if moved is None:  # the static scene: the surface point stays where the camera saw it
        moved = transform_points(frame.T_world_cam, frame.camera.backproject(np.where(surface, frame.depth, np.nan)))
    u, v = frame.camera.project(transform_points(invert_pose(T_other), moved))
    gu, gv = pixel_grid(*frame.run.shape)
    ref = np.stack([u - gu, v - gv], axis=-1)
    ref_ok = np.all(np.isfinite(ref), axis=-1) & surface & frame.static
    have = np.all(np.isfinite(flow), axis=-1)
    both = ref_ok & have
    med = p99 = missing = float("nan")
    if both.any():
        epe = np.linalg.norm(flow[both].astype(np.float64) - ref[both], axis=-1)
        med, p99 = median_p99(epe)
        frame.add(d.check, "median endpoint error", med, tol.flow_median_px, unit="px")
        frame.add(d.check, "p99 endpoint error", p99, tol.flow_p99_px, unit="px")
    if ref_ok.any():
        missing = float((ref_ok & ~have).sum() / ref_ok.sum())
        frame.add(d.check, "surface pixels without flow (frac)", missing, tol.flow_missing)
    if frame.errors is None:
        return None
    value = np.full(frame.run.shape, np.nan, np.float32)
    if both.any():
        value[both] = epe
    title = f"{d.key.split('_')[1]} flow endpoint error to frame {other}"
    panel = ErrorPanel(value, pixel_states(ref_ok, have, frame.static), title,
                       f"median {fmt(med, 'px')}, p99 {fmt(p99, 'px')}")
    score = worst(ratio(med, tol.flow_median_px), ratio(p99, tol.flow_p99_px), ratio(missing, tol.flow_missing))
    return score, panel
