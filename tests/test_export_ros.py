"""``rgbd2scene export-ros``: bags read back with readers independent of the writer (``rosbags``):
``mcap-ros2-support`` for ROS 2 (MCAP) and the standalone ROS 1 ``rosbag`` package for ``.bag`` files."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
import yaml

from rgbd2scene.cli import main
from rgbd2scene.conventions import invert_pose
from rgbd2scene.dataset import Dataset
from rgbd2scene.export.ros import DEFAULT_START_S, RosTopics
from rgbd2scene.groundtruth.synthetic import write_plane_dataset

FRAMES = 4
RATE = 12.5
TOPICS = RosTopics.with_prefix("/stereo")
PER_FRAME = (TOPICS.tf, TOPICS.left_image, TOPICS.left_info, TOPICS.right_image, TOPICS.right_info,
             TOPICS.disparity, TOPICS.depth, TOPICS.segmentation)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return Dataset(write_plane_dataset(tmp_path_factory.mktemp("plane") / "ds", FRAMES))


def _stamp(header) -> int:
    stamp = header.stamp
    return stamp.sec * 1_000_000_000 + stamp.nanosec if hasattr(stamp, "nanosec") else stamp.to_nsec()


def _matrix(transform) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q, t = transform.rotation, transform.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = t.x, t.y, t.z
    return T


def _check_messages(dataset: Dataset, messages: dict, bag_times: dict, field) -> None:
    """Topics, counts, stamps (= bag times, spaced 1/RATE), CameraInfo, one depth and disparity value, tf."""
    assert set(messages) == {*PER_FRAME, TOPICS.tf_static}
    assert len(messages[TOPICS.tf_static]) == 1
    expected = [DEFAULT_START_S * 10**9 + round(i * 1e9 / RATE) for i in range(FRAMES)]
    for topic in PER_FRAME:
        assert len(messages[topic]) == FRAMES, topic
        assert bag_times[topic] == expected, topic
        if topic not in (TOPICS.tf,):
            assert [_stamp(m.header) for m in messages[topic]] == expected, topic
    assert np.diff(expected).tolist() == [80_000_000] * (FRAMES - 1)  # 1/12.5 Hz
    K = dataset.K
    for eye, topic in (("left", TOPICS.left_info), ("right", TOPICS.right_info)):
        info = messages[topic][0]
        assert info.header.frame_id == f"endoscope_{eye}_optical_frame"
        assert info.distortion_model == "plumb_bob" and list(field(info, "d")) == [0.0] * 5
        np.testing.assert_allclose(np.reshape(field(info, "k"), (3, 3)), K)
        np.testing.assert_allclose(np.reshape(field(info, "r"), (3, 3)), np.eye(3))
        P = np.reshape(field(info, "p"), (3, 4))
        np.testing.assert_allclose(P[:, :3], K)
        assert P[0, 3] == pytest.approx(-dataset.fx * dataset.baseline if eye == "right" else 0.0)
    frame = 2
    gt = dataset.gt("left", frame)
    v, u = 10, 7  # a pixel on the plane
    assert np.isfinite(gt["depth"][v, u])
    depth_msg = messages[TOPICS.depth][frame]
    assert depth_msg.encoding == "32FC1" and depth_msg.step == 4 * dataset.width
    depth = np.frombuffer(bytes(depth_msg.data), "<f4").reshape(dataset.height, dataset.width)
    assert depth[v, u] == gt["depth"][v, u]
    np.testing.assert_array_equal(np.isnan(depth), np.isnan(gt["depth"]))  # REP 118: NaN where no surface
    disp_msg = messages[TOPICS.disparity][frame]
    assert disp_msg.f == dataset.fx and field(disp_msg, "t") == pytest.approx(dataset.baseline)
    assert disp_msg.image.encoding == "32FC1"
    disparity = np.frombuffer(bytes(disp_msg.image.data), "<f4").reshape(dataset.height, dataset.width)
    assert disparity[v, u] == gt["disparity"][v, u]
    invalid = disparity < disp_msg.min_disparity
    np.testing.assert_array_equal(invalid, np.isnan(gt["disparity"]))
    assert disp_msg.max_disparity >= np.nanmax(gt["disparity"])
    seg = messages[TOPICS.segmentation][frame]
    assert seg.encoding == "16UC1"
    np.testing.assert_array_equal(np.frombuffer(bytes(seg.data), "<u2").reshape(dataset.height, dataset.width),
                                  gt["segmentation"])
    image = messages[TOPICS.right_image][frame]
    assert image.encoding == "rgb8"
    np.testing.assert_array_equal(np.frombuffer(bytes(image.data), np.uint8).reshape(dataset.height, dataset.width, 3),
                                  dataset.rgb("right", frame))
    # tf: capture_optical_frame -> left optical frame through the tree equals the dataset's T_world_cam
    static = {t.child_frame_id: (t.header.frame_id, _matrix(t.transform))
              for t in messages[TOPICS.tf_static][0].transforms}
    moving = {t.child_frame_id: (t.header.frame_id, _matrix(t.transform))
              for t in messages[TOPICS.tf][frame].transforms}
    assert static["capture_optical_frame"][0] == "world" and moving["endoscope"][0] == "world"
    assert static["endoscope_left_optical_frame"][0] == "endoscope"
    for eye in ("left", "right"):
        T_world_eye = invert_pose(static["capture_optical_frame"][1]) @ moving["endoscope"][1] @ \
            static[f"endoscope_{eye}_optical_frame"][1]
        np.testing.assert_allclose(T_world_eye, dataset.pose(eye, frame), atol=1e-9)
    np.testing.assert_allclose(invert_pose(static["capture_optical_frame"][1]) @ moving["object_1"][1],
                               gt["object_poses"][0], atol=1e-9)


def test_ros2_mcap_read_back_with_mcap_ros2(dataset, tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag = tmp_path / "bag2"
    assert main(["export-ros", str(dataset.root), "-o", str(bag), "--ros", "2", "--rate", str(RATE), "--quiet"]) == 0
    mcaps = list(bag.glob("*.mcap"))
    assert [p.name for p in mcaps] == ["bag2.mcap"]
    messages, times = defaultdict(list), defaultdict(list)
    with mcaps[0].open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            messages[channel.topic].append(decoded)
            times[channel.topic].append(message.log_time)
    _check_messages(dataset, messages, times, getattr)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 8 and meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["bag2.mcap"]
    qos = {t["topic_metadata"]["name"]: yaml.safe_load(t["topic_metadata"]["offered_qos_profiles"])
           for t in meta["topics_with_message_count"]}
    assert isinstance(meta["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"], str)  # Humble
    assert qos["/tf_static"][0]["durability"] == 1 and qos["/tf_static"][0]["depth"] == 1  # transient local
    assert qos["/tf"][0]["durability"] == 2  # volatile
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts[TOPICS.left_image] == FRAMES and counts["/tf_static"] == 1


def test_ros1_bag_read_back_with_standalone_rosbag(dataset, tmp_path):
    rosbag = pytest.importorskip("rosbag")
    out = tmp_path / "out.bag"
    assert main(["export-ros", str(dataset.root), "-o", str(out), "--ros", "1", "--rate", str(RATE), "--quiet"]) == 0
    messages, times = defaultdict(list), defaultdict(list)
    with rosbag.Bag(str(out)) as bag:
        latching = {c.topic: c.header.get("latching") for c in bag._connections.values()}
        for topic, msg, t in bag.read_messages():
            messages[topic].append(msg)
            times[topic].append(t.to_nsec())
    assert latching["/tf_static"] == b"1" and latching["/tf"] is None

    def field(msg, name):  # ROS 1 spells CameraInfo's D, K, R, P and DisparityImage's T in capitals
        return getattr(msg, name.upper())

    _check_messages(dataset, messages, times, field)
    assert [m.header.seq for m in messages[TOPICS.left_image]] == list(range(FRAMES))


def test_bags_are_reproducible_and_atomic(dataset, tmp_path):
    a, b = tmp_path / "a.bag", tmp_path / "b.bag"
    for out in (a, b):
        assert main(["export-ros", str(dataset.root), "-o", str(out), "--ros", "1", "--quiet"]) == 0
    assert a.read_bytes() == b.read_bytes()
    # rewriting a ROS 2 bag folder replaces it whole
    bag = tmp_path / "bag"
    for _ in range(2):
        assert main(["export-ros", str(dataset.root), "-o", str(bag), "--quiet", "--prefix", "/dvrk/ECM"]) == 0
    assert sorted(p.name for p in bag.iterdir()) == ["bag.mcap", "metadata.yaml"]
    assert "/dvrk/ECM/left/image_rect_color" in (bag / "metadata.yaml").read_text()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("args, message", [
    (["--rate", "0"], "rate"), (["--rate", "nan"], "rate"), (["--start", "-5"], "start")])
def test_export_ros_bad_options_exit_2(dataset, tmp_path, capsys, args, message):
    assert main(["export-ros", str(dataset.root), "-o", str(tmp_path / "x"), "--quiet", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "x").exists()


def test_export_ros_bad_paths_exit_2(dataset, tmp_path, capsys):
    assert main(["export-ros", str(tmp_path / "nothing"), "-o", str(tmp_path / "x"), "--quiet"]) == 2
    assert "dataset.json" in capsys.readouterr().err
    folder = tmp_path / "folder"
    folder.mkdir()
    assert main(["export-ros", str(dataset.root), "-o", str(folder), "--ros", "1", "--quiet"]) == 2
    assert "folder" in capsys.readouterr().err
    blocker = tmp_path / "blocker"  # a file where the bag's folder should be: unwritable even for root
    blocker.write_text("x")
    assert main(["export-ros", str(dataset.root), "-o", str(blocker / "b.bag"), "--ros", "1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {blocker / 'b.bag'}: cannot write") and err.count("\n") == 1
