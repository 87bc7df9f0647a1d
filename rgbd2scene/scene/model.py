"""Renderer-independent scene description (what ``scene.json`` records and ``render/`` builds).

Like Kubric, the description knows nothing of Blender: the ``render`` package turns it into a
``.blend``. Everything needed to rebuild the scene is here.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from rgbd2scene.scene.materials import TissueDetail
from rgbd2scene.scene.path import CameraPath
from rgbd2scene.scene.rig import StereoRig

MATERIALS = ("as_captured", "wet_tissue")


@dataclass
class Light:
    """Light at the endoscope tip, rigidly attached to the left eye (offset in its OpenCV frame)."""

    kind: str = "spot"  # "spot" or "point"; inverse-square falloff either way
    power_w: float = 0.5
    spot_size_deg: float = 100.0
    offset: tuple[float, float, float] = (0.0025, 0.0, 0.0)  # between the eyes, at the tip
    radius: float = 0.0005

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Light:
        d = dict(d)
        d["offset"] = tuple(d.get("offset", (0.0025, 0.0, 0.0)))
        return cls(**d)


@dataclass
class SceneObject:
    """An object with an instance id in the segmentation maps (0 is reserved for nothing)."""

    id: int
    name: str
    part: str = "surface"
    cls: str = "tissue"
    moving: bool = False

    def to_dict(self) -> dict:
        return {"id": self.id, "name": self.name, "part": self.part, "class": self.cls, "moving": self.moving}

    @classmethod
    def from_dict(cls, d: dict) -> SceneObject:
        return cls(int(d["id"]), d["name"], d.get("part", "surface"), d.get("class", "tissue"),
                   bool(d.get("moving", False)))


@dataclass
class SceneDescription:
    """Stereo rig on a path, light at its tip, the tissue mesh and its look."""

    rig: StereoRig
    path: CameraPath
    light: Light = field(default_factory=Light)
    material: str = "wet_tissue"
    mesh_file: str = "mesh.ply"
    texture_file: str = "texture.png"
    objects: list[SceneObject] = field(default_factory=lambda: [SceneObject(1, "tissue")])
    tissue_detail: TissueDetail = field(default_factory=TissueDetail)  # of the "wet_tissue" material

    def to_dict(self) -> dict:
        return {"rig": self.rig.to_dict(), "path": self.path.to_dict(), "light": self.light.to_dict(),
                "material": self.material, "mesh_file": self.mesh_file, "texture_file": self.texture_file,
                "objects": [o.to_dict() for o in self.objects], "tissue_detail": self.tissue_detail.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> SceneDescription:
        # a description without "tissue_detail" was written before the detail existed: its scene has none
        detail = d.get("tissue_detail", {"enabled": False})
        return cls(StereoRig.from_dict(d["rig"]), CameraPath.from_dict(d["path"]),
                   Light.from_dict(d.get("light", {})), d.get("material", "wet_tissue"),
                   d.get("mesh_file", "mesh.ply"), d.get("texture_file", "texture.png"),
                   [SceneObject.from_dict(o) for o in d.get("objects", [])], TissueDetail.from_dict(detail))
