"""ROS bag export for replay (``rgbd2scene export-ros``): ROS 1 ``.bag`` or ROS 2 bag (MCAP storage), no ROS needed.

Both are written with ``rosbags``; messages come from its type stores (ROS 2 Humble types; ROS 1 Noetic types,
plus ``tf2_msgs/TFMessage``, which that store lacks, registered from its one-line definition, whose MD5 equals
ROS 1's). The dataset is streamed: one frame is read, written and dropped at a time.

Topics (``prefix`` defaults to ``/stereo``; e.g. ``--prefix /dvrk/ECM`` mimics another driver's names)::

    {prefix}/left/image_rect_color    sensor_msgs/Image rgb8          left image
    {prefix}/left/camera_info         sensor_msgs/CameraInfo          left camera
    {prefix}/right/image_rect_color   sensor_msgs/Image rgb8          right image
    {prefix}/right/camera_info        sensor_msgs/CameraInfo          right camera
    {prefix}/disparity                stereo_msgs/DisparityImage      left disparity (rectified datasets)
    {prefix}/depth/image_rect         sensor_msgs/Image 32FC1         left depth in metres, NaN = no surface
                                                                      (REP 118)
    {prefix}/left/segmentation        sensor_msgs/Image 16UC1         left instance ids, 0 = nothing
    /tf                               tf2_msgs/TFMessage              world -> endoscope, world -> object_<id>
    /tf_static                        tf2_msgs/TFMessage              the rig and the capture frame, once,
                                                                      latched (ROS 1) / transient local (ROS 2)

CameraInfo (CONVENTIONS §2): for the rectified pair plumb_bob with D = 0, R = I, K and P from the dataset's K,
right P[0,3] = -fx·B; for a raw pair each eye's real D (plumb_bob or rational_polynomial) and K, with R and P
of its rectification (``cv2.stereoRectify``, alpha 0). DisparityImage: f = fx, T = B, the disparity in
pixels with invalid pixels set to min_disparity - 1 = -1 (the message's rule: "less than min_disparity is
invalid"; min_disparity = 0), max_disparity = the frame's largest disparity rounded up, delta_d = the float32
step at that value (the map is continuous, not quantised), valid_window the whole image.

Frames (REP 103 / 105; ``world`` and ``endoscope`` are configurable names):

- ``world``: fixed, REP 103 axes (x forward, y left, z up) placed at the capture camera. The dataset's world
  frame (the capture camera frame, OpenCV axes) is ``capture_optical_frame``, a static child of ``world``.
- ``endoscope``: the scope tip, REP 103 axes (x along the view), at the left eye; moves on ``/tf``.
- ``endoscope_left_optical_frame`` / ``endoscope_right_optical_frame``: the eyes, optical axes (z forward,
  x right, y down: the dataset's camera frame); static children of ``endoscope``. Looking up
  ``capture_optical_frame`` -> ``endoscope_left_optical_frame`` gives the dataset's T_world_cam exactly.
- ``object_<id>``: every tracked object part and tracked frame of the npz's ``object_ids``, on ``/tf`` as a
  child of ``world`` (T_world_obj); dataset.json maps ids to names.

Time: frame i has header stamp and bag time ``start + i / rate`` (nanoseconds, equal), so ``rosbag play`` /
``ros2 bag play`` replays at ``rate`` as if a camera captured it; ``/tf_static`` is written once at the first
stamp. The default start is a fixed epoch, so the same dataset and options give the same messages.

ROS 2 bags use metadata version 8: the newest whose QoS profiles are a YAML string, the form Humble's reader
parses (version 9 made them a list); newer fields (type hashes, distro) are ignored by older readers. Every
topic offers reliable, volatile, keep-last QoS, ``/tf_static`` reliable, transient-local, keep-last 1 (as
tf2's static broadcaster). Bags are written under a temporary name and renamed into place when complete.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import invert_pose
from rgbd2scene.dataset.layout import EYES
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError
from rgbd2scene.export.common import ExportSummary, complete_frames, frame_indices
from rgbd2scene.files.atomic import atomic_place
from rgbd2scene.scene.rig import StereoRig

#: 2024-01-01T00:00:00Z: the default first stamp (a fixed epoch: reproducible bags; not 0, which tf reads as
#: "latest available")
DEFAULT_START_S = 1_704_067_200
ROS2_METADATA_VERSION = 8
#: REP 103 body axes (x forward, y left, z up) from optical axes (z forward, x right, y down): p_body = R p_opt
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0],
                              [0.0, 0.0, 0.0, 1.0]])
CAPTURE_FRAME = "capture_optical_frame"
IMAGE, CAMERA_INFO, DISPARITY, TF = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                                     "stereo_msgs/msg/DisparityImage", "tf2_msgs/msg/TFMessage")
_TFMESSAGE_ROS1 = "geometry_msgs/TransformStamped[] transforms"


@dataclass(frozen=True)
class RosTopics:
    """Topic names of one export (see the module docstring)."""

    left_image: str
    left_info: str
    right_image: str
    right_info: str
    disparity: str
    depth: str
    segmentation: str
    tf: str = "/tf"
    tf_static: str = "/tf_static"

    @classmethod
    def with_prefix(cls, prefix: str = "/stereo") -> RosTopics:
        p = "/" + prefix.strip("/") if prefix.strip("/") else ""
        return cls(f"{p}/left/image_rect_color", f"{p}/left/camera_info", f"{p}/right/image_rect_color",
                   f"{p}/right/camera_info", f"{p}/disparity", f"{p}/depth/image_rect", f"{p}/left/segmentation")


@dataclass(frozen=True)
class RosOptions:
    """``version`` 1 (``.bag``) or 2 (MCAP bag folder); ``rate`` in Hz (None: the dataset's fps); ``start``
    the first stamp in seconds since the Unix epoch; topic ``prefix``; ``world`` and ``scope`` frame names."""

    version: int = 2
    rate: float | None = None
    start: float = DEFAULT_START_S
    prefix: str = "/stereo"
    world: str = "world"
    scope: str = "endoscope"

    def __post_init__(self):
        if self.version not in (1, 2):
            raise ValueError(f"ROS version must be 1 or 2, got {self.version}")
        if self.rate is not None and not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"rate must be a positive number of Hz, got {self.rate}")
        if not (math.isfinite(self.start) and self.start > 0):
            raise ValueError(f"start must be a positive number of seconds, got {self.start}")

    @property
    def left_frame(self) -> str:
        return f"{self.scope}_left_optical_frame"

    @property
    def right_frame(self) -> str:
        return f"{self.scope}_right_optical_frame"


def stamp_ns(index: int, rate: float, start: float = DEFAULT_START_S) -> int:
    """Header stamp and bag time (ns) of frame ``index``: start + index / rate."""
    return int(round(start * 1e9)) + int(round(index * 1e9 / rate))


def camera_info_matrices(rig: StereoRig, eye: str) -> dict[str, np.ndarray]:
    """D, K, R, P of one eye: for the rectified pair D = 0, R = I, P = [K | 0] (P[0,3] = -fx·B on the right);
    for a raw pair the eye's own D and K, and R, P of its rectification (``cv2.stereoRectify``, alpha 0), as
    ROS's stereo_image_proc expects them."""
    rect = rig.calibration.rectification()
    R, P = rect.eye(eye)
    camera = rig.camera(eye)
    return {"d": camera.distortion, "k": camera.K.ravel(), "r": np.asarray(R, np.float64).ravel(),
            "p": np.asarray(P, np.float64).ravel(), "distortion_model": camera.distortion_model}


def disparity_message_values(disparity: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """(image with invalid = -1, min_disparity 0, max_disparity, delta_d) of a DisparityImage."""
    d = np.asarray(disparity, np.float32)
    valid = np.isfinite(d) & (d > 0)
    max_d = float(np.ceil(d[valid].max())) if valid.any() else 1.0
    return np.where(valid, d, np.float32(-1.0)), 0.0, max_d, float(np.spacing(np.float32(max_d)))


def static_transforms(dataset: Dataset, options: RosOptions) -> list[tuple[str, str, np.ndarray]]:
    """(parent, child, 4x4) of ``/tf_static``: world -> capture frame, endoscope -> each eye (the rig of the
    first frame)."""
    first = complete_frames(dataset)[0]
    T_left_right = invert_pose(dataset.pose("left", first)) @ dataset.pose("right", first)
    return [(options.world, CAPTURE_FRAME, BODY_FROM_OPTICAL),
            (options.scope, options.left_frame, BODY_FROM_OPTICAL),
            (options.scope, options.right_frame, BODY_FROM_OPTICAL @ T_left_right)]


def scope_pose(T_world_left: np.ndarray) -> np.ndarray:
    """T_{world, endoscope} (REP 103 frames) from the dataset's T_world_cam of the left eye."""
    return BODY_FROM_OPTICAL @ T_world_left @ invert_pose(BODY_FROM_OPTICAL)


class _Messages:
    """Builds serialized messages of one ROS version from a rosbags type store."""

    def __init__(self, version: int):
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.version = version
        if version == 1:
            self.store = get_typestore(Stores.ROS1_NOETIC)
            self.store.register(get_types_from_msg(_TFMESSAGE_ROS1, TF))
        else:
            self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.types = self.store.types
        self.seq = 0

    def make(self, msgtype: str, **values):
        """A message with fields by name, case-insensitively (ROS 1 spells CameraInfo's ``D``, ``K``, ``R``, ``P``
        and DisparityImage's ``T`` in capitals, ROS 2 in lower case)."""
        spelling = {name.lower(): name for name, _ in self.store.fielddefs[msgtype][1]}
        return self.types[msgtype](**{spelling[k.lower()]: v for k, v in values.items()})

    def header(self, stamp: int, frame_id: str):
        sec, nanosec = divmod(stamp, 1_000_000_000)
        values = {"stamp": self.make("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec), "frame_id": frame_id}
        if self.version == 1:
            values["seq"] = self.seq
        return self.make("std_msgs/msg/Header", **values)

    def serialize(self, msg, msgtype: str) -> bytes:
        if self.version == 1:
            return self.store.serialize_ros1(msg, msgtype)
        return self.store.serialize_cdr(msg, msgtype)

    def image(self, stamp: int, frame_id: str, array: np.ndarray, encoding: str):
        a = np.ascontiguousarray(array)
        h, w = a.shape[:2]
        return self.make(IMAGE, header=self.header(stamp, frame_id), height=h, width=w, encoding=encoding,
                         is_bigendian=0, step=a.strides[0], data=a.view(np.uint8).ravel())

    def camera_info(self, stamp: int, frame_id: str, width: int, height: int, matrices: dict):
        roi = self.make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0,
                        do_rectify=False)
        return self.make(CAMERA_INFO, header=self.header(stamp, frame_id), height=height, width=width,
                         binning_x=0, binning_y=0, roi=roi, **matrices)

    def disparity(self, stamp: int, frame_id: str, disparity: np.ndarray, fx: float, baseline: float):
        image, min_d, max_d, delta = disparity_message_values(disparity)
        h, w = image.shape
        window = self.make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=h, width=w,
                           do_rectify=False)
        return self.make(DISPARITY, header=self.header(stamp, frame_id),
                         image=self.image(stamp, frame_id, image, "32FC1"), f=float(fx), T=float(baseline),
                         valid_window=window, min_disparity=min_d, max_disparity=max_d, delta_d=delta)

    def tf(self, stamp: int, transforms: list[tuple[str, str, np.ndarray]]):
        from scipy.spatial.transform import Rotation

        items = []
        for parent, child, T in transforms:
            x, y, z, w = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_quat()
            tx, ty, tz = (float(v) for v in np.asarray(T)[:3, 3])
            transform = self.make("geometry_msgs/msg/Transform",
                                  translation=self.make("geometry_msgs/msg/Vector3", x=tx, y=ty, z=tz),
                                  rotation=self.make("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w))
            items.append(self.make("geometry_msgs/msg/TransformStamped", header=self.header(stamp, parent),
                                   child_frame_id=child, transform=transform))
        return self.make(TF, transforms=items)


def _qos(latched: bool):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    unset = QosTime(0, 0)  # the rmw default: no deadline, lifespan or lease (what every distro reads the same)
    return Qos(QosHistory.KEEP_LAST, 1 if latched else 10, QosReliability.RELIABLE,
               QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE, unset, unset,
               QosLiveliness.AUTOMATIC, unset, False)


class _BagWriter:
    """One interface over rosbags' ROS 1 and ROS 2 writers: ``add(topic, msgtype, latched)``, ``write``."""

    def __init__(self, path: Path, messages: _Messages):
        self.messages = messages
        if messages.version == 1:
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            self.writer = Writer(path, version=ROS2_METADATA_VERSION, storage_plugin=StoragePlugin.MCAP)
        self.connections: dict[str, tuple] = {}

    def __enter__(self) -> _BagWriter:
        self.writer.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        return self.writer.__exit__(exc_type, exc, tb)

    def add(self, topic: str, msgtype: str, latched: bool = False) -> None:
        store = self.messages.store
        if self.messages.version == 1:
            conn = self.writer.add_connection(topic, msgtype, typestore=store, latching=1 if latched else None)
        else:
            conn = self.writer.add_connection(topic, msgtype, typestore=store, offered_qos_profiles=[_qos(latched)])
        self.connections[topic] = (conn, msgtype)

    def write(self, topic: str, stamp: int, msg) -> None:
        conn, msgtype = self.connections[topic]
        self.writer.write(conn, stamp, self.messages.serialize(msg, msgtype))


def check_bag_path(out: Path, version: int) -> None:
    """A ROS 1 bag is a file, a ROS 2 bag a folder: refuse an existing path of the other kind."""
    if version == 1 and out.is_dir():
        raise UserError(f"{out}: is a folder; a ROS 1 bag is a file (e.g. {out.name}.bag)")
    if version == 2 and out.exists() and not out.is_dir():
        raise UserError(f"{out}: is a file; a ROS 2 bag is a folder (metadata.yaml and an .mcap file)")


def export_ros(dataset: Dataset, out: str | Path, options: RosOptions | None = None,
               progress: bool = True) -> ExportSummary:
    """Write ``dataset`` as a ROS bag at ``out`` (see the module docstring); returns the summary."""
    options = options or RosOptions()
    out = Path(out)
    check_bag_path(out, options.version)
    rate = options.rate or dataset.fps
    topics = RosTopics.with_prefix(options.prefix)
    messages = _Messages(options.version)
    summary = ExportSummary(f"ros{options.version}", out)
    width, height, fx, baseline = dataset.width, dataset.height, dataset.fx, dataset.baseline
    info = {eye: camera_info_matrices(dataset.rig, eye) for eye in EYES}
    frame_ids = {"left": options.left_frame, "right": options.right_frame}
    static = static_transforms(dataset, options)
    try:
        with atomic_place(out) as tmp, _BagWriter(tmp, messages) as bag:
            bag.add(topics.tf_static, TF, latched=True)
            rectified = dataset.rectified  # a raw pair has no disparity: its topic is left out
            for topic, msgtype in ((topics.tf, TF), (topics.left_image, IMAGE), (topics.left_info, CAMERA_INFO),
                                   (topics.right_image, IMAGE), (topics.right_info, CAMERA_INFO),
                                   (topics.disparity, DISPARITY), (topics.depth, IMAGE),
                                   (topics.segmentation, IMAGE)):
                if rectified or topic != topics.disparity:
                    bag.add(topic, msgtype)
            first = True
            for index in frame_indices(dataset, progress, f"export ros{options.version}"):
                stamp = stamp_ns(index, rate, options.start)
                if first:
                    bag.write(topics.tf_static, stamp, messages.tf(stamp, static))
                    first = False
                left = dataset.gt("left", index, ("depth", "segmentation", "T_world_cam", "object_ids",
                                                  "object_poses"), optional=("disparity",))
                moving = [(options.world, options.scope, scope_pose(left["T_world_cam"]))]
                moving += [(options.world, f"object_{int(oid)}", BODY_FROM_OPTICAL @ T)
                           for oid, T in zip(left["object_ids"], left["object_poses"], strict=True)]
                bag.write(topics.tf, stamp, messages.tf(stamp, moving))
                for eye, image_topic, info_topic in (("left", topics.left_image, topics.left_info),
                                                     ("right", topics.right_image, topics.right_info)):
                    bag.write(image_topic, stamp, messages.image(stamp, frame_ids[eye], dataset.rgb(eye, index),
                                                                 "rgb8"))
                    bag.write(info_topic, stamp, messages.camera_info(stamp, frame_ids[eye], width, height,
                                                                      info[eye]))
                if rectified:
                    bag.write(topics.disparity, stamp, messages.disparity(stamp, frame_ids["left"],
                                                                          left["disparity"], fx, baseline))
                bag.write(topics.depth, stamp, messages.image(stamp, frame_ids["left"],
                                                              left["depth"].astype("<f4"), "32FC1"))
                bag.write(topics.segmentation, stamp, messages.image(stamp, frame_ids["left"],
                                                                     left["segmentation"].astype("<u2"), "16UC1"))
                messages.seq += 1
                summary.frames += 1
    except OSError as exc:
        raise UserError(f"{out}: cannot write the bag ({exc.strerror or exc})") from None
    summary.files = 1
    summary.notes.append(f"{summary.frames} frames at {rate:g} Hz, first stamp {stamp_ns(0, rate, options.start)} ns")
    return summary
