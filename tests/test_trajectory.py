"""Trajectory files (TUM, Redwood/Open3D .log): parsing, bad lines, matching poses to frames, world = frame 0."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rgbd2scene.capture.trajectory import associate, parse_log, parse_tum, read_trajectory, relative_to_first


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


POSES = np.array([_pose([0.1, -0.2, 0.3], [1.0, 2.0, 3.0]), _pose([0.0, 0.5, 0.0], [1.1, 2.0, 2.9]),
                  _pose([-0.3, 0.1, 0.2], [0.9, 2.2, 3.1])])
STAMPS = [1305031102.175304, 1305031102.211214, 1305031102.243211]


def tum_text(poses=POSES, stamps=STAMPS) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for s, T in zip(stamps, poses, strict=True):
        q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x, y, z, w
        lines.append(" ".join(f"{x:.9f}" for x in [s, *T[:3, 3], *q]))
    return "\n".join(lines) + "\n"


def log_text(poses=POSES, ids=(0, 1, 2)) -> str:
    blocks = []
    for i, T in zip(ids, poses, strict=True):
        blocks.append(f"{i} {i} {i + 1}")
        blocks += [" ".join(f"{x:.12g}" for x in row) for row in T]
    return "\n".join(blocks) + "\n"


def test_tum_quaternions_scalar_last_give_camera_to_world():
    traj = parse_tum(tum_text())
    assert traj.fmt == "tum" and np.allclose(traj.stamps, STAMPS)
    assert np.allclose(traj.poses, POSES, atol=1e-8)
    # a hand-checked line: 90 degrees about z, scalar last; the camera x axis points along world y
    one = parse_tum("0.5 1 2 3 0 0 0.7071068 0.7071068\n").poses[0]
    assert np.allclose(one[:3, 0], [0, 1, 0], atol=1e-6) and np.allclose(one[:3, 3], [1, 2, 3])


def test_log_matrices_are_camera_to_world_rows(tmp_path):
    path = tmp_path / "traj.log"
    path.write_text(log_text(ids=(5, 6, 7)))
    traj = read_trajectory(path)
    assert traj.fmt == "log" and traj.ids.tolist() == [5, 6, 7]
    assert np.allclose(traj.poses, POSES, atol=1e-10)
    # detected by content too, whatever the suffix
    other = tmp_path / "poses.txt"
    other.write_text(log_text())
    assert read_trajectory(other).fmt == "log"


def test_redwood_sample_log_matches_open3d(shared_samples):
    o3d = pytest.importorskip("open3d")
    path = shared_samples / "redwood_livingroom1_5frames_open3d" / "trajectory.log"
    traj = read_trajectory(path)
    extrinsics = [p.extrinsic for p in o3d.io.read_pinhole_camera_trajectory(str(path)).parameters]
    assert np.allclose(traj.poses, np.linalg.inv(np.array(extrinsics)), atol=1e-9)  # Open3D reports world-to-cam


@pytest.mark.parametrize("text, message", [
    ("1.0 1 2 3 0 0 0\n", "line 1: expected 8 numbers"),
    ("# c\n1.0 1 2 3 0 0 0 1\n2.0 1 2 x 0 0 0 1\n", "line 3: not a number"),
    ("1.0 1 2 3 0 0 0 2\n", "line 1: quaternion"),
    ("2.0 1 2 3 0 0 0 1\n1.0 1 2 3 0 0 0 1\n", "timestamps must increase"),
    ("1.0 1 2 nan 0 0 0 1\n", "line 1: non-finite"),
    ("# only comments\n", "no pose found"),
])
def test_bad_tum_lines_name_the_line(text, message):
    with pytest.raises(ValueError, match=message):
        parse_tum(text)


@pytest.mark.parametrize("mutate, message", [
    (lambda lines: lines[:3], "line 3: the file ends inside a pose"),
    (lambda lines: [lines[0], "1 0 0", *lines[2:]], "line 2: expected 4 numbers"),
    (lambda lines: ["0 0", *lines[1:]], "line 1: expected a metadata line"),
    (lambda lines: [*lines[:4], "0 0 1 1", *lines[5:]], "lines 2-5: last row"),
    (lambda lines: [lines[0], "2 0 0 0", *lines[2:]], "lines 2-5: the 3x3 part is not a rotation"),
])
def test_bad_log_blocks_name_the_lines(mutate, message):
    lines = log_text().splitlines()
    with pytest.raises(ValueError, match=message):
        parse_log("\n".join(mutate(lines)))


def test_association_by_timestamp_nearest_within_tolerance():
    traj = parse_tum(tum_text())
    names = ["rgb/1305031102.243000.png", "rgb/1305031102.176000.png"]
    match = associate(traj, names)
    assert match.rule == "timestamp" and match.indices.tolist() == [2, 0]
    assert match.max_time_difference_s < 0.001
    with pytest.raises(ValueError, match="1305031102.300000.png: the nearest pose is 0.057 s away"):
        associate(traj, ["rgb/1305031102.300000.png"])


def test_association_by_order_and_by_log_frame_id():
    by_order = associate(parse_tum(tum_text()), ["a.png", "b.png", "c.png"])
    assert by_order.rule == "order" and np.array_equal(by_order.poses, parse_tum(tum_text()).poses)
    log = parse_log(log_text(ids=(10, 11, 12)))
    by_id = associate(log, ["color/00012.jpg", "color/00010.jpg"])
    assert by_id.rule == "id" and by_id.indices.tolist() == [2, 0]
    with pytest.raises(ValueError, match="00013.jpg: no pose with frame id 13"):
        associate(log, ["color/00013.jpg"])
    with pytest.raises(ValueError, match="3 poses for 2 frames"):
        associate(parse_tum(tum_text()), ["a.png", "b.png"])


def test_relative_to_first_makes_frame_zero_the_world():
    rel = relative_to_first(POSES)
    assert np.allclose(rel[0], np.eye(4))
    # relative motion between any two frames is unchanged
    for a, b in ((0, 1), (1, 2)):
        assert np.allclose(np.linalg.inv(rel[a]) @ rel[b], np.linalg.inv(POSES[a]) @ POSES[b])
