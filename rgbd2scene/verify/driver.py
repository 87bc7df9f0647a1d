"""``verify_dataset``: load a dataset, build its scene oracle, run the registered checks on every frame.

The checks live in ``verify/checks/`` (one module each, registered in ``checks.CHECKS``), the per-frame views
they read and the metric collector in ``verify/framework.py``, the ray-casting reference in
``verify/oracle.py``, the report in ``verify/report.py`` and the error-map pictures in ``verify/error_maps.py``.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from rgbd2scene.dataset.layout import DATASET_JSON, EYES, frame_paths
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError
from rgbd2scene.verify.checks import CHECKS
from rgbd2scene.verify.error_maps import FrameErrors, keep_worst, write_error_maps
from rgbd2scene.verify.framework import Check, EyeFrame, PairFrame, Tolerances, VerifyRun
from rgbd2scene.verify.oracle import SHADINGS, SceneOracle, scene_oracle
from rgbd2scene.verify.report import VerifyReport

#: Largest change of an object pose over the frames that still counts as not moving.
STILL_POSE = 1e-9


def verify_dataset(dataset_dir: str | Path, mesh_path: str | Path | None = None,
                   tolerances: Tolerances | None = None, *, progress: bool = True, frames: Iterable[int] | None = None,
                   normals: str = "smooth", mesh_ids: Iterable[int] | None = None,
                   error_maps: str | Path | None = None, checks: Sequence[Check] = CHECKS,
                   oracle: SceneOracle | None = None, blender_frames: int = 0) -> VerifyReport:
    """Check a dataset folder (CONVENTIONS.md section 4) for self-consistency.

    Parameters
    ----------
    dataset_dir : the dataset folder (with ``dataset.json``).
    mesh_path : the scene mesh; default ``dataset.json``'s ``scene.mesh`` (or ``scene.dir``/mesh.ply).
        Without a mesh the checks that need the oracle (depth, normals) are skipped (reported as skip).
    tolerances : pass limits (:class:`Tolerances`).
    progress : show a tqdm progress bar over frames (stderr).
    frames : optional frame numbers to check (default all).
    normals : how the oracle shades: ``"smooth"`` (interpolated vertex normals: a smooth-shaded render) or
        ``"face"``.
    mesh_ids : segmentation ids of the mesh's surface (default: objects of class "tissue" in the object
        table, else every id); pixels of other objects, and of moving ones, are left out of the mesh checks.
    error_maps : optional folder for error-map pictures: per eye, one PNG of the worst frame of the depth
        check (``depth_left_frame000012.png``) and, where it is another frame, one of the worst frame of
        the flow check (``flow_left_frame000007.png``); see ``error_maps.render_error_map``. Their paths are
        listed in ``report.error_maps``. Only the worst frame's maps are held in memory.
    checks : the checks to run (default all registered ones, ``checks.CHECKS``).
    oracle : the scene model to ray cast instead of the scene mesh (a :class:`~rgbd2scene.verify.oracle.SceneOracle`,
        e.g. one that poses moving objects per frame); ``mesh_path``, ``normals`` and ``mesh_ids`` then do not apply.
    blender_frames : render this many sampled frames' passes with Blender and compare the maps with them (the
        independent second source of the ground truth, :mod:`rgbd2scene.verify.passes`; needs ``bpy``).
    """
    from tqdm import tqdm

    t_start = time.perf_counter()
    if oracle is not None and mesh_path is not None:
        raise ValueError("give mesh_path or oracle, not both")
    if normals not in SHADINGS:
        raise ValueError(f"normals must be one of {SHADINGS}, not {normals!r}")
    dataset = Dataset(dataset_dir)
    try:
        width, height, count, baseline, K = dataset.width, dataset.height, dataset.frames, dataset.baseline, dataset.K
    except (TypeError, ValueError) as exc:
        raise UserError(f"{dataset.root / DATASET_JSON}: bad value ({exc})") from None
    maps_dir = None
    if error_maps is not None:
        from rgbd2scene.files.atomic import ensure_output_dir

        maps_dir = ensure_output_dir(error_maps)

    poses, object_poses = _read_poses(dataset)
    moving = _moving_ids(dataset, object_poses)
    no_oracle = ""
    if oracle is None:
        oracle, no_oracle = scene_oracle(dataset, mesh_path, shading=normals, ids=mesh_ids, moving=moving)
    if hasattr(oracle, "moved_points"):  # the oracle follows moving and deforming surfaces itself
        moving = frozenset()
    run = VerifyRun(dataset, width, height, baseline, K, tolerances or Tolerances(), oracle, moving, poses)
    active = [check for check in checks if oracle is not None or not check.needs_oracle]
    for check in checks:
        if check in active:
            check.declare(run)
        else:
            run.collector.skips.update({(name, eye): no_oracle for name in check.names for eye in EYES})

    keep: dict[tuple[str, str], FrameErrors] | None = {} if maps_dir is not None else None
    frame_times = []
    for index in tqdm(sorted(set(range(count) if frames is None else (int(f) for f in frames))), desc="verify",
                      unit="frame", disable=not progress):
        t_frame = time.perf_counter()
        eyes = {eye: _eye_frame(run, eye, index, keep is not None) for eye in EYES}
        for frame in eyes.values():
            for check in active:
                if check.applies_to(frame):
                    check.check_eye(frame)
        left, right = eyes.values()
        if left.usable and right.usable:
            pair = PairFrame(left, right)
            for check in active:
                if check.applies_to(left) and check.applies_to(right):
                    check.check_pair(pair)
        if keep is not None:
            keep_worst(keep, {eye: frame.errors for eye, frame in eyes.items() if frame.errors is not None})
        frame_times.append(time.perf_counter() - t_frame)

    written = write_error_maps(maps_dir, keep, run.tol, dataset.root.name) if keep is not None else []
    notes = [f"moving object ids {sorted(moving)} left out of mesh and flow checks"] if moving else []
    if blender_frames:
        from rgbd2scene.verify.passes import blender_crosscheck

        note = blender_crosscheck(run, blender_frames)
        notes += [note] if note else []
    return VerifyReport(str(dataset.root), width, height, count, oracle.source if oracle is not None else None,
                        run.collector.results(name for check in checks for name in check.names), run.problems,
                        time.perf_counter() - t_start, float(np.mean(frame_times)) if frame_times else float("nan"),
                        notes, written)


def _eye_frame(run: VerifyRun, eye: str, index: int, error_maps: bool) -> EyeFrame:
    """One eye of one frame, read through the dataset reader (``gt`` None when missing or unreadable)."""
    path = frame_paths(run.dataset.root, eye, index).gt
    name = path.relative_to(run.dataset.root)
    if not path.is_file():
        return EyeFrame(run, eye, index, None, f"missing {name}")
    try:
        gt = run.dataset.gt(eye, index)
    except UserError:
        return EyeFrame(run, eye, index, None, f"unreadable {name}")
    frame = EyeFrame(run, eye, index, gt)
    if frame.usable:
        run.keep_depth(eye, index, gt["depth"])
        if error_maps:
            frame.errors = FrameErrors(eye, index, gt["depth"])
    return frame


def _read_poses(dataset: Dataset) -> tuple[dict[tuple[str, int], np.ndarray], dict[int, list[np.ndarray]]]:
    """T_world_cam of every readable (eye, frame), and each object's poses over the frames (left eye)."""
    poses, object_poses = {}, {}
    for eye in EYES:
        for index in range(dataset.frames):
            try:
                T = np.asarray(dataset.pose(eye, index), dtype=np.float64)
            except (UserError, TypeError, ValueError):  # reported when the frame itself is checked
                continue
            if T.shape == (4, 4):
                poses[(eye, index)] = T
    for index in range(dataset.frames):
        try:
            gt = dataset.gt(EYES[0], index, keys=("object_ids", "object_poses"))
            pairs = list(zip(gt["object_ids"].tolist(), np.asarray(gt["object_poses"], np.float64), strict=False))
        except (UserError, TypeError, ValueError):
            continue
        for oid, T in pairs:
            if T.shape == (4, 4):
                object_poses.setdefault(int(oid), []).append(T)
    return poses, object_poses


def _moving_ids(dataset: Dataset, object_poses: dict[int, list[np.ndarray]]) -> frozenset[int]:
    """Objects marked moving in the object table or whose pose changes over the frames (not tracked frames,
    which never appear in the segmentation)."""
    table = dataset.objects
    moving = {oid for oid, entry in table.items() if entry.moving}
    moving |= {oid for oid, Ts in object_poses.items() if any(np.abs(T - Ts[0]).max() > STILL_POSE for T in Ts)}
    return frozenset(oid for oid in moving if oid not in table or not table[oid].tracked_frame)
