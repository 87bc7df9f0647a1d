"""Exports of a dataset folder to other tools' formats: ROS bags for replay and standard dataset layouts.

``FORMATS`` maps each ``rgbd2scene export --format`` name to its writer, ``writer(dataset, out, progress)``;
``export_ros`` writes ROS 1/2 bags (``rgbd2scene export-ros``). Every module's docstring lists its layout and
how its conventions differ from the dataset's.
"""

from rgbd2scene.export.common import ExportSummary
from rgbd2scene.export.kitti import export_kitti
from rgbd2scene.export.ros import RosOptions, RosTopics, export_ros
from rgbd2scene.export.sceneflow import export_sceneflow
from rgbd2scene.export.visionblender import export_visionblender

FORMATS = {"kitti": export_kitti, "sceneflow": export_sceneflow, "visionblender": export_visionblender}

__all__ = ["FORMATS", "ExportSummary", "RosOptions", "RosTopics", "export_kitti", "export_ros", "export_sceneflow",
           "export_visionblender"]
