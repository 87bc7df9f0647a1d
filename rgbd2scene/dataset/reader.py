"""Read a dataset folder (CONVENTIONS.md section 4) as objects: frames, both eyes, maps, poses, the id table.

``verify``, the pictures, the exporters and ``evaluate`` read datasets through :class:`Dataset` instead of
parsing ``dataset.json`` and npz keys themselves.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from rgbd2scene.dataset.layout import EYES, frame_done, frame_paths, read_dataset_json
from rgbd2scene.errors import UserError
from rgbd2scene.files.images import read_image


@dataclass(frozen=True)
class ObjectEntry:
    """One row of the id table: an object part (in ``segmentation``) or a tracked frame (never in it)."""

    id: int
    name: str
    part: str = ""
    cls: str = ""
    moving: bool = False
    tracked_frame: bool = False
    attached_to: str | None = None


class Dataset:
    """A rendered dataset folder.

    Parameters
    ----------
    root
        The folder holding ``dataset.json``.

    Examples
    --------
    >>> ds = Dataset("out/dataset")                          # doctest: +SKIP
    >>> gt = ds.gt("left", 0, keys=("depth", "disparity"))   # doctest: +SKIP
    """

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.meta = read_dataset_json(self.root)
        for key in ("width", "height", "frames", "K", "baseline"):
            if key not in self.meta:
                raise UserError(f"{self.root / 'dataset.json'}: missing key {key!r}")

    # -- the record --
    @property
    def width(self) -> int:
        return int(self.meta["width"])

    @property
    def height(self) -> int:
        return int(self.meta["height"])

    @property
    def frames(self) -> int:
        return int(self.meta["frames"])

    @property
    def fps(self) -> float:
        return float(self.meta.get("fps", 30.0))

    @property
    def baseline(self) -> float:
        return float(self.meta["baseline"])

    @property
    def K(self) -> np.ndarray:
        return np.asarray(self.meta["K"], dtype=np.float64).reshape(3, 3)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @cached_property
    def rig(self):
        """The stereo rig as rendered (:class:`~rgbd2scene.scene.rig.StereoRig`): ``dataset.json``'s
        ``"camera"`` record (CONVENTIONS 1.2), else the rectified pair of its K and baseline."""
        from rgbd2scene.geometry.camera import Camera
        from rgbd2scene.geometry.stereo import StereoCalibration
        from rgbd2scene.scene.rig import StereoRig

        record = self.meta.get("camera")
        if isinstance(record, dict) and "left" in record:
            try:
                return StereoRig(StereoCalibration(Camera.from_dict(record["left"]), Camera.from_dict(record["right"]),
                                                   record["R"], record["T"]))
            except (KeyError, TypeError, ValueError) as exc:
                raise UserError(f"{self.root / 'dataset.json'}: bad 'camera' record ({exc})") from None
        return StereoRig.parallel(Camera.from_K(self.K, self.width, self.height), self.baseline)

    @property
    def rectified(self) -> bool:
        return self.rig.rectified

    @cached_property
    def objects(self) -> dict[int, ObjectEntry]:
        """Object parts and tracked frames by id (dict or legacy list form of ``objects``)."""
        table = self.meta.get("objects") or {}
        items = table.items() if isinstance(table, dict) else enumerate(table) if isinstance(table, list) else []
        out: dict[int, ObjectEntry] = {}
        for key, entry in items:
            try:
                if isinstance(entry, dict):
                    oid = int(entry.get("id", key))
                    out[oid] = ObjectEntry(oid, str(entry.get("name", oid)), str(entry.get("part", "")),
                                           str(entry.get("class", "")), bool(entry.get("moving", False)))
                else:
                    out[int(key)] = ObjectEntry(int(key), str(entry))
            except (TypeError, ValueError):
                continue
        frames = self.meta.get("tracked_frames") or {}
        if isinstance(frames, dict):
            for key, entry in frames.items():
                entry = entry if isinstance(entry, dict) else {"name": str(entry)}
                out[int(key)] = ObjectEntry(int(key), str(entry.get("name", key)), cls="tracked_frame",
                                            tracked_frame=True, attached_to=entry.get("attached_to"))
        return out

    @property
    def classes(self) -> dict[str, int]:
        """Class name -> class id (CONVENTIONS §3); derived from the object table when absent."""
        classes = self.meta.get("classes")
        if isinstance(classes, dict):
            return {str(k): int(v) for k, v in classes.items()}
        names = sorted({o.cls for o in self.objects.values() if not o.tracked_frame and o.cls})
        return {name: i + 1 for i, name in enumerate(names)}

    # -- frames --
    def frame_indices(self, complete: bool = True) -> list[int]:
        """Frame numbers of the dataset; with ``complete``, only those whose files are all present."""
        gt = bool(self.meta.get("render", {}).get("gt", True))
        return [i for i in range(self.frames) if not complete or frame_done(self.root, i, gt=gt)]

    def rgb_file(self, eye: str, index: int) -> Path:
        """Path of one eye's 8-bit sRGB PNG of frame ``index`` (exporters copy its bytes as they are)."""
        return frame_paths(self.root, eye, index).rgb

    def rgb(self, eye: str, index: int) -> np.ndarray:
        """RGB uint8 (H, W, 3) of one eye and frame."""
        path = self.rgb_file(eye, index)
        image = read_image(path)
        if image is None:
            raise UserError(f"{path}: missing or unreadable image")
        return image

    def gt(self, eye: str, index: int, keys: Iterable[str] | None = None,
           optional: Iterable[str] = ()) -> dict[str, np.ndarray]:
        """Ground-truth arrays of one eye and frame: all keys, or only ``keys`` (a missing one is an error)
        plus those of ``optional`` that the file holds (e.g. ``occluded_forward``)."""
        path = frame_paths(self.root, eye, index).gt
        if not path.is_file():
            raise UserError(f"{path}: ground-truth file missing")
        try:
            with np.load(path, allow_pickle=False) as z:
                names = z.files if keys is None else list(keys)
                missing = [k for k in names if k not in z.files]
                if missing:
                    hint = ("a raw (distorted) pair has correspondence, not disparity: render --rectify for "
                            "disparity" if "disparity" in missing and not self.rectified else "rendered with --gt?")
                    raise UserError(f"{path}: no {', '.join(missing)} in this file ({hint})")
                names += [k for k in optional if k in z.files and k not in names]
                return {k: z[k] for k in names}
        except UserError:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged npz raises BadZipFile, zlib.error, TokenError, ...
            raise UserError(f"{path}: unreadable ground truth ({exc})") from None

    def pose(self, eye: str, index: int) -> np.ndarray:
        """T_world_cam (4, 4) of one eye and frame."""
        return self.gt(eye, index, keys=("T_world_cam",))["T_world_cam"]

    def iter_frames(self, eyes: Iterable[str] = EYES, keys: Iterable[str] | None = None,
                    rgb: bool = False) -> Iterator[tuple[int, str, np.ndarray | None, dict]]:
        """(index, eye, RGB or None, gt) of every complete frame, one at a time (memory stays flat)."""
        keys = None if keys is None else tuple(keys)
        for index in self.frame_indices():
            for eye in eyes:
                yield index, eye, self.rgb(eye, index) if rgb else None, self.gt(eye, index, keys)

    # -- the scene it came from --
    @property
    def scene_dir(self) -> Path | None:
        """The scene folder (stored relative to the dataset; older datasets hold an absolute path)."""
        return self._scene_path("dir")

    @property
    def scene_mesh(self) -> Path | None:
        """The scene's mesh file as recorded (``scene.mesh``; relative to the dataset, like :attr:`scene_dir`)."""
        return self._scene_path("mesh")

    def _scene_path(self, key: str) -> Path | None:
        scene = self.meta.get("scene") or {}
        where = scene.get(key) if isinstance(scene, dict) else None
        if not where:
            return None
        p = Path(where)
        return p if p.is_absolute() else (self.root / p)

