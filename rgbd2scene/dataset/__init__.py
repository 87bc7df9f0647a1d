"""The dataset folder: its layout (paths, atomic frame files, dataset.json) and a reader for it."""

from rgbd2scene.dataset.layout import (
    DATASET_JSON,
    EYES,
    WORK_DIR,
    FramePaths,
    frame_done,
    frame_name,
    frame_paths,
    geometry_path,
    gt_done,
    read_dataset_json,
    read_frame,
    rgb_done,
    scratch_dir,
    sweep_dead_runs,
    write_dataset_json,
    write_frame,
    write_gt,
)
from rgbd2scene.dataset.reader import Dataset, ObjectEntry

__all__ = ["DATASET_JSON", "Dataset", "EYES", "FramePaths", "ObjectEntry", "WORK_DIR", "frame_done", "frame_name",
           "frame_paths", "geometry_path", "gt_done", "read_dataset_json", "read_frame", "rgb_done", "scratch_dir",
           "sweep_dead_runs", "write_dataset_json", "write_frame", "write_gt"]
