"""The renderer-independent scene model: what ``scene.json`` records, ``render/`` builds and keys from,
the dataset writer takes poses from and ``verify`` ray-casts (no ``bpy`` here).

Like Kubric's core, the model knows nothing of Blender. It answers "where is everything at frame f" in
plain numpy (float64):

- the **camera** is the stereo rig on its track (:class:`~rgbd2scene.scene.paths.CameraPath`): the
  left eye's ``T_world_cam`` per frame, the right eye +baseline along the left x axis;
- every **object** (the tissue surface is one) owns its geometry, material, parts, motion and tracked
  frames. A **part** is one rigid piece with one instance id (1..65535) in the segmentation maps and a
  class; its geometry file (PLY, metres, in the part's own frame, relative to the scene folder) is posed
  by ``T_world_part`` per frame. ``object_ids`` / ``object_poses`` of every frame are
  :meth:`SceneDescription.tracked_poses`.

Adding an object kind is one entry here (a ``kind`` name the builder registry in ``render/`` knows) and
one builder function there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rgbd2scene.scene import folder
from rgbd2scene.scene.deformation import Deformation, SurfaceAnchor, rotation_between
from rgbd2scene.scene.materials import TissueDetail
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig

#: Looks of the tissue surface: the texture's colours exactly (unlit), or lit glossy wet tissue.
MATERIALS = ("as_captured", "wet_tissue")
TISSUE_ID = 1
TISSUE_CLASS = "tissue"
MAX_ID = 65535
#: Blender's spot blend of the scope light (the render's cone edge; the de-lighting models the same cone).
SPOT_BLEND = 0.5


@dataclass
class Light:
    """Light at the endoscope tip, rigidly attached to the left eye (offset in its OpenCV frame).

    ``outlets`` 2 splits ``power_w`` over two fibre outlets ``outlet_spacing`` apart along the camera's x axis,
    centred on ``offset``: a stereo scope's light guides end beside its two lenses.
    """

    kind: str = "spot"  # "spot" or "point"; inverse-square falloff either way
    power_w: float = 0.5
    spot_size_deg: float = 100.0
    offset: tuple[float, float, float] = (0.0025, 0.0, 0.0)  # between the eyes, at the tip
    radius: float = 0.0005
    outlets: int = 1
    outlet_spacing: float = 0.0

    def outlet_offsets(self) -> list[tuple[float, float, float]]:
        """Position of each outlet in the left eye's OpenCV frame (metres)."""
        x, y, z = self.offset
        if self.outlets == 1:
            return [(x, y, z)]
        half = 0.5 * self.outlet_spacing
        return [(x - half, y, z), (x + half, y, z)]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "power_w": self.power_w, "spot_size_deg": self.spot_size_deg,
                "offset": list(self.offset), "radius": self.radius, "outlets": self.outlets,
                "outlet_spacing": self.outlet_spacing}

    @classmethod
    def from_dict(cls, d: dict) -> Light:
        d = dict(d)
        d["offset"] = tuple(d.get("offset", (0.0025, 0.0, 0.0)))
        return cls(**d)


@dataclass
class Material:
    """How a part looks. ``kind`` names a material builder in ``render/`` (e.g. ``wet_tissue``);
    ``texture`` is an image file in the scene folder mapped by the geometry's UVs; without it the
    geometry's vertex colours are used, and without those ``color`` (linear RGB, 0-1)."""

    kind: str = "wet_tissue"
    texture: str | None = None
    color: tuple[float, float, float] | None = None
    detail: TissueDetail | None = None  # procedural micro-structure (the wet_tissue look)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "texture": self.texture, "color": None if self.color is None else list(self.color),
                "detail": None if self.detail is None else self.detail.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> Material:
        color, detail = d.get("color"), d.get("detail")
        return cls(str(d.get("kind", "wet_tissue")), d.get("texture"), None if color is None else tuple(color),
                   None if detail is None else TissueDetail.from_dict(detail))


def _poses_array(poses) -> np.ndarray | None:
    if poses is None:
        return None
    a = np.asarray(poses, dtype=np.float64)
    if a.shape == (4, 4):
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (4, 4) or not np.isfinite(a).all():
        raise ValueError(f"poses must be finite 4x4 matrices, shape (F, 4, 4); got {a.shape}")
    return a


def _pose_at(poses: np.ndarray | None, frame: int) -> np.ndarray:
    """The pose of ``frame`` (identity without poses; one pose = static; the last pose after the end)."""
    if poses is None:
        return np.eye(4)
    return poses[min(max(int(frame), 0), len(poses) - 1)].copy()


@dataclass
class Part:
    """One rigid piece of an object with its own instance id and class.

    ``poses`` are ``T_world_part`` (F, 4, 4) float64, one per frame (a single pose: static); None means
    the part's frame is the world frame (the reconstructed tissue). ``deformation`` moves its vertices
    along their rest normals over time (:mod:`rgbd2scene.scene.deformation`), in the part's frame.
    """

    id: int
    name: str
    cls: str
    geometry: str
    material: Material = field(default_factory=Material)
    poses: np.ndarray | None = None
    deformation: Deformation | None = None

    def __post_init__(self):
        self.id = int(self.id)
        if not 1 <= self.id <= MAX_ID:
            raise ValueError(f"part {self.name!r}: instance id {self.id} is not in 1..{MAX_ID}")
        self.poses = _poses_array(self.poses)

    def pose_at(self, frame: int) -> np.ndarray:
        return _pose_at(self.poses, frame)

    @property
    def moving(self) -> bool:
        """Whether the part moves or deforms over the frames (rigid motion or a deformation)."""
        rigid = self.poses is not None and len(self.poses) > 1 and not np.all(self.poses == self.poses[0])
        return rigid or (self.deformation is not None and self.deformation.amplitude_m > 0)

    def to_dict(self) -> dict:
        return {"id": self.id, "name": self.name, "class": self.cls, "geometry": self.geometry,
                "material": self.material.to_dict(),
                "poses": None if self.poses is None else self.poses.tolist(),
                "deformation": None if self.deformation is None else self.deformation.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> Part:
        deformation = d.get("deformation")
        return cls(int(d["id"]), str(d["name"]), str(d.get("class", "")), str(d["geometry"]),
                   Material.from_dict(d.get("material") or {}), d.get("poses"),
                   None if deformation is None else Deformation.from_dict(deformation))


@dataclass
class TrackedFrame:
    """A named coordinate frame attached to a part: ``T_world_frame = T_world_part @ offset``.

    With an ``anchor`` (a point of the part's surface, see :class:`SurfaceAnchor`) the frame also follows
    the part's deformation: its origin is the deformed surface point and it turns with the surface
    normal there (at rest, ``offset`` is the frame, its origin the anchor point). Its id appears in
    ``object_ids``/``object_poses`` but never in ``segmentation``.
    """

    id: int
    name: str
    attached_to: str  # name of the part it moves with
    offset: np.ndarray = field(default_factory=lambda: np.eye(4))
    anchor: SurfaceAnchor | None = None

    def __post_init__(self):
        self.id = int(self.id)
        if not 1 <= self.id <= MAX_ID:
            raise ValueError(f"tracked frame {self.name!r}: id {self.id} is not in 1..{MAX_ID}")
        self.offset = np.asarray(self.offset, dtype=np.float64).reshape(4, 4)

    def local_pose(self, deformation: Deformation | None, t: float) -> np.ndarray:
        """The frame in its part's frame at time ``t`` (seconds)."""
        if self.anchor is None or deformation is None:
            return self.offset.copy()
        T = np.eye(4)
        T[:3, :3] = rotation_between(self.anchor.normal(), self.anchor.normal(deformation, t)) @ self.offset[:3, :3]
        T[:3, 3] = self.offset[:3, 3] + self.anchor.point(deformation, t) - self.anchor.point()
        return T

    def to_dict(self) -> dict:
        return {"id": self.id, "name": self.name, "attached_to": self.attached_to, "offset": self.offset.tolist(),
                "anchor": None if self.anchor is None else self.anchor.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> TrackedFrame:
        anchor = d.get("anchor")
        return cls(int(d["id"]), str(d["name"]), str(d["attached_to"]), d.get("offset", np.eye(4)),
                   None if anchor is None else SurfaceAnchor.from_dict(anchor))


@dataclass
class SceneObject:
    """An object: a ``kind`` (the builder ``render/`` uses), its parts and its tracked frames."""

    name: str
    kind: str
    parts: list[Part]
    tracked_frames: list[TrackedFrame] = field(default_factory=list)

    @property
    def moving(self) -> bool:
        return any(p.moving for p in self.parts)

    def part(self, name: str) -> Part:
        for p in self.parts:
            if p.name == name:
                return p
        raise KeyError(f"object {self.name!r} has no part {name!r}")

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "parts": [p.to_dict() for p in self.parts],
                "tracked_frames": [t.to_dict() for t in self.tracked_frames]}

    @classmethod
    def from_dict(cls, d: dict) -> SceneObject:
        return cls(str(d["name"]), str(d["kind"]), [Part.from_dict(p) for p in d["parts"]],
                   [TrackedFrame.from_dict(t) for t in d.get("tracked_frames", [])])


def tissue_object(material: str = "wet_tissue", geometry: str = folder.MESH,
                  texture: str | None = folder.TEXTURE, detail: TissueDetail | None = None) -> SceneObject:
    """The reconstructed tissue surface: one part (id 1, class tissue) whose frame is the world frame."""
    return SceneObject("tissue", "tissue", [Part(TISSUE_ID, "surface", TISSUE_CLASS, geometry,
                                                 Material(material, texture, detail=detail))])


@dataclass
class SceneDescription:
    """The stereo rig on its camera track, the light at its tip, and the objects (tissue first)."""

    rig: StereoRig
    path: CameraPath
    light: Light = field(default_factory=Light)
    objects: list[SceneObject] = field(default_factory=lambda: [tissue_object()])
    #: fields of :class:`rgbd2scene.environment.EnvironmentOptions` the scene sets (smoke, ...): RGB only
    environment: dict = field(default_factory=dict)

    def __post_init__(self):
        ids = [p.id for o in self.objects for p in o.parts] + [t.id for o in self.objects for t in o.tracked_frames]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"instance ids used twice: {dup}")
        for o in self.objects:
            names = {p.name for p in o.parts}
            for t in o.tracked_frames:
                if t.attached_to not in names:
                    raise ValueError(f"tracked frame {t.name!r} is attached to {t.attached_to!r}, "
                                     f"not a part of object {o.name!r}")

    @property
    def frames(self) -> int:
        return self.path.frames

    def parts(self) -> list[tuple[SceneObject, Part]]:
        return [(o, p) for o in self.objects for p in o.parts]

    def time(self, frame: int) -> float:
        """Seconds at ``frame`` (the camera path's fps)."""
        return float(frame) / float(self.path.fps)

    @property
    def deforming(self) -> bool:
        return any(p.deformation is not None for _, p in self.parts())

    def camera_pose(self, frame: int, eye: str = "left") -> np.ndarray:
        """T_world_cam (OpenCV axes) of one eye at ``frame``, float64."""
        T = np.asarray(self.path.T_world_cam[int(frame)], dtype=np.float64)
        return T.copy() if eye == "left" else self.rig.right_pose(T)

    def tracked_poses(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """``object_ids`` (N,) uint16 and ``object_poses`` (N, 4, 4) float64 at ``frame``: every part, then
        every tracked frame, in model order."""
        ids, poses = [], []
        for _, part in self.parts():
            ids.append(part.id)
            poses.append(part.pose_at(frame))
        for obj in self.objects:
            for t in obj.tracked_frames:
                part = obj.part(t.attached_to)
                ids.append(t.id)
                poses.append(part.pose_at(frame) @ t.local_pose(part.deformation, self.time(frame)))
        return np.asarray(ids, np.uint16), np.asarray(poses, np.float64).reshape(-1, 4, 4)

    def classes(self) -> dict[str, int]:
        """Class name -> class id (1.. in order of first appearance; 0 is nothing)."""
        out: dict[str, int] = {}
        for _, part in self.parts():
            out.setdefault(part.cls, len(out) + 1)
        return out

    def object_table(self) -> dict:
        """dataset.json's ``objects``, ``classes`` and ``tracked_frames`` (CONVENTIONS §3)."""
        objects = {str(p.id): {"name": o.name, "part": p.name, "class": p.cls, "moving": p.moving, "kind": o.kind}
                   for o, p in self.parts()}
        frames = {str(t.id): {"name": t.name, "attached_to": f"{o.name}/{t.attached_to}"}
                  for o in self.objects for t in o.tracked_frames}
        return {"objects": objects, "classes": self.classes(), "tracked_frames": frames}

    def to_dict(self) -> dict:
        out = {"model_version": 2, "rig": self.rig.to_dict(), "path": self.path.to_dict(),
               "light": self.light.to_dict(), "objects": [o.to_dict() for o in self.objects]}
        if self.environment:
            out["environment"] = dict(self.environment)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> SceneDescription:
        objects = d.get("objects", [])
        if "mesh_file" in d or any("parts" not in o for o in objects):  # model version 1 (one tissue mesh)
            objects = [tissue_object(d.get("material", "wet_tissue"), d.get("mesh_file", folder.MESH),
                                     d.get("texture_file", folder.TEXTURE))]
        else:
            objects = [SceneObject.from_dict(o) for o in objects]
        return cls(StereoRig.from_dict(d["rig"]), CameraPath.from_dict(d["path"]),
                   Light.from_dict(d.get("light", {})), objects, dict(d.get("environment") or {}))
