"""Camera trajectories of RGB-D sequences: TUM and Redwood/Open3D ``.log`` files, and matching poses to frames.

Both formats hold camera-to-world poses ``T_world_cam`` in OpenCV camera axes (x right, y down, z forward):

- **TUM** (``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments; commas or tabs also separate):
  the position and orientation (unit quaternion, scalar last) of the colour camera's optical centre.
- **Redwood/Open3D** ``.log``: blocks of five lines, a metadata line of three integers (the first is the
  frame id) and the 4x4 matrix row by row. ``o3d.io.read_pinhole_camera_trajectory`` reads the same
  file and reports the *inverse* (world-to-camera) as ``extrinsic``.

Which pose belongs to which frame (:func:`associate`), in this order of preference:

1. **timestamp** (TUM only): when every frame's file name is a timestamp (a decimal number with a
   fractional part, as TUM names ``rgb/1305031102.175304.png``), each frame takes the pose with the
   nearest timestamp, which must lie within ``max_time_difference`` (0.02 s, the default of TUM's
   ``associate.py``).
2. **order**: when the trajectory has exactly as many poses as there are frames, pose k is frame k's.
3. **id** (``.log`` only): when the names are integers (Redwood's ``00042.png``), frame ``00042`` takes
   the block whose metadata line starts with 42.

Anything else is an error. :func:`relative_to_first` re-expresses poses so that the first frame's camera
frame is the world frame (CONVENTIONS section 1). Errors are ``ValueError`` naming the line (or frame);
the command line adds the file name.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import invert_pose

#: Largest deviation from orthonormality of a pose's rotation (files print about 6 significant digits).
ROTATION_TOLERANCE = 1e-3
#: Largest |norm - 1| of a TUM quaternion before it is normalised (TUM prints 4 decimals).
QUATERNION_TOLERANCE = 1e-2
#: TUM's associate.py default: frames and poses further apart in time do not match (seconds).
MAX_TIME_DIFFERENCE = 0.02

_TIMESTAMP_NAME = re.compile(r"^\d+\.\d+$")
_INTEGER_NAME = re.compile(r"^\d+$")


@dataclass
class Trajectory:
    """Camera poses read from a file.

    poses : float64 (N, 4, 4) ``T_world_cam`` (OpenCV camera axes) in the file's world frame.
    fmt : ``"tum"`` or ``"log"``.
    stamps : float64 (N,) seconds (TUM), or None.
    ids : int64 (N,) frame ids of the metadata lines (``.log``), or None.
    """

    poses: np.ndarray
    fmt: str
    stamps: np.ndarray | None = None
    ids: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.poses)


@dataclass
class Association:
    """Which trajectory entry each frame took: ``poses`` (F, 4, 4) in the file's world frame, ``indices``
    (F,) into the trajectory, the ``rule`` used (timestamp, order or id) and, for timestamps, the largest
    time difference in seconds."""

    poses: np.ndarray
    indices: np.ndarray
    rule: str
    max_time_difference_s: float | None = None


def _split(line: str) -> list[str]:
    return line.replace(",", " ").replace("\t", " ").split()


def _numbers(fields: list[str], lineno: int) -> np.ndarray:
    try:
        values = np.array([float(x) for x in fields])
    except ValueError:
        raise ValueError(f"line {lineno}: not a number in {' '.join(fields)!r}") from None
    if not np.isfinite(values).all():
        raise ValueError(f"line {lineno}: non-finite value in {' '.join(fields)!r}")
    return values


def check_pose(T: np.ndarray, where: str) -> None:
    """Raise ``ValueError`` (starting with ``where``) unless ``T`` is a rigid 4x4 transform."""
    R = T[:3, :3]
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise ValueError(f"{where}: last row of the pose must be 0 0 0 1, got {T[3].tolist()}")
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
        raise ValueError(f"{where}: the 3x3 part is not a rotation (|R R^T - I| = {err:.2g}, "
                         f"det {np.linalg.det(R):.3g})")


def parse_tum(text: str) -> Trajectory:
    """Poses of a TUM trajectory (``timestamp tx ty tz qx qy qz qw`` per line); see the module docstring."""
    from scipy.spatial.transform import Rotation  # here: every capture command imports this module at start-up

    stamps, poses = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        fields = _split(line)
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) != 8:
            raise ValueError(f"line {lineno}: expected 8 numbers (timestamp tx ty tz qx qy qz qw), "
                             f"got {len(fields)}")
        values = _numbers(fields, lineno)
        quat = values[4:8]
        norm = np.linalg.norm(quat)
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise ValueError(f"line {lineno}: quaternion (qx qy qz qw) has norm {norm:.4g}, not 1")
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(quat / norm).as_matrix()  # scipy order is (x, y, z, w), as TUM's
        T[:3, 3] = values[1:4]
        stamps.append(values[0])
        poses.append(T)
    if not poses:
        raise ValueError("no pose found (expected lines 'timestamp tx ty tz qx qy qz qw')")
    stamps = np.array(stamps)
    if np.any(np.diff(stamps) <= 0):
        bad = int(np.flatnonzero(np.diff(stamps) <= 0)[0])
        raise ValueError(f"timestamps must increase; pose {bad + 2} ({stamps[bad + 1]}) follows {stamps[bad]}")
    return Trajectory(np.array(poses), "tum", stamps=stamps)


def parse_log(text: str) -> Trajectory:
    """Poses of a Redwood/Open3D ``.log`` trajectory (metadata line + 4 matrix rows per frame)."""
    rows = [(n, _split(line)) for n, line in enumerate(text.splitlines(), start=1)]
    rows = [(n, f) for n, f in rows if f]
    ids, poses = [], []
    for start in range(0, len(rows), 5):
        block = rows[start:start + 5]
        lineno, meta = block[0]
        if len(meta) != 3 or not all(_INTEGER_NAME.match(x.lstrip("-")) for x in meta):
            raise ValueError(f"line {lineno}: expected a metadata line of 3 integers (frame ids), "
                             f"got {' '.join(meta)!r}")
        if len(block) < 5:
            raise ValueError(f"line {block[-1][0]}: the file ends inside a pose (need 4 rows of 4 numbers "
                             f"after the metadata line {lineno})")
        matrix = []
        for n, fields in block[1:]:
            if len(fields) != 4:
                raise ValueError(f"line {n}: expected 4 numbers of a pose row, got {len(fields)}")
            matrix.append(_numbers(fields, n))
        T = np.array(matrix)
        check_pose(T, f"lines {block[1][0]}-{block[4][0]}")
        ids.append(int(meta[0]))
        poses.append(T)
    if not poses:
        raise ValueError("no pose found (expected blocks of a metadata line and 4 rows of 4 numbers)")
    return Trajectory(np.array(poses), "log", ids=np.array(ids, dtype=np.int64))


def read_trajectory(path: str | Path) -> Trajectory:
    """Read a TUM or ``.log`` trajectory; ``.log`` files by suffix, others by content.

    A file whose first data line holds 3 integers is a ``.log`` file; one with 8 numbers per line is TUM.
    Raises ``OSError`` when unreadable and ``ValueError`` (with the line number) when malformed.
    """
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    if Path(path).suffix.lower() == ".log":
        return parse_log(text)
    for line in text.splitlines():
        fields = _split(line)
        if fields and not fields[0].startswith("#"):
            return parse_log(text) if len(fields) == 3 else parse_tum(text)
    raise ValueError("no pose found (empty trajectory file)")


def associate(trajectory: Trajectory, frame_names: list[str],
              max_time_difference: float = MAX_TIME_DIFFERENCE) -> Association:
    """The pose of each frame (file names, in the order given); the rules are in the module docstring."""
    stems = [Path(name).stem for name in frame_names]
    n_frames, n_poses = len(stems), len(trajectory)
    if trajectory.stamps is not None and stems and all(_TIMESTAMP_NAME.match(s) for s in stems):
        times = np.array([float(s) for s in stems])
        stamps = trajectory.stamps
        after = np.searchsorted(stamps, times)
        lo, hi = np.clip(after - 1, 0, n_poses - 1), np.clip(after, 0, n_poses - 1)
        nearest = np.where(np.abs(stamps[lo] - times) <= np.abs(stamps[hi] - times), lo, hi)
        dt = np.abs(stamps[nearest] - times)
        if dt.max() > max_time_difference:
            k = int(np.argmax(dt))
            raise ValueError(f"frame {frame_names[k]}: the nearest pose is {dt[k]:.3f} s away (more than "
                             f"{max_time_difference} s)")
        return Association(trajectory.poses[nearest], nearest, "timestamp", float(dt.max()))
    if n_poses == n_frames:
        return Association(trajectory.poses.copy(), np.arange(n_frames), "order")
    if trajectory.ids is not None and stems and all(_INTEGER_NAME.match(s) for s in stems):
        where = {int(i): k for k, i in enumerate(trajectory.ids)}
        missing = [name for name, s in zip(frame_names, stems, strict=True) if int(s) not in where]
        if missing:
            raise ValueError(f"frame {missing[0]}: no pose with frame id {int(Path(missing[0]).stem)}")
        indices = np.array([where[int(s)] for s in stems])
        return Association(trajectory.poses[indices], indices, "id")
    names = "timestamps" if trajectory.fmt == "tum" else "frame ids"
    raise ValueError(f"{n_poses} poses for {n_frames} frames, and the frame file names are not {names}: "
                     "give one pose per frame, in order")


def relative_to_first(poses: np.ndarray) -> np.ndarray:
    """Poses (F, 4, 4) re-expressed in the first pose's frame: ``T_0^-1 T_k`` (so the first becomes I)."""
    poses = np.asarray(poses, dtype=np.float64)
    return invert_pose(poses[0]) @ poses
