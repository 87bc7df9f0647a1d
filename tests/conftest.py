"""Shared test fixtures: paths to the real captures in ../shared (skipped with a reason when absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_SAMPLES = REPO.parent / "shared" / "rgbd_samples"
BUNDLED_SAMPLE = REPO / "data_samples" / "tissue"


@pytest.fixture
def shared_samples() -> Path:
    if not SHARED_SAMPLES.is_dir():
        pytest.skip(f"real captures not available: {SHARED_SAMPLES} is absent")
    return SHARED_SAMPLES


def write_scene_files(folder: Path, mesh, description=None) -> Path:
    """Write ``mesh`` (any object with vertices, triangles and optional uvs, vertex_colors, texture) as the
    tissue files of a scene folder; point the description's tissue at the texture, or at the vertex
    colours when the mesh has none."""
    from rgbd2scene.files.images import write_image
    from rgbd2scene.files.meshio import write_ply
    from rgbd2scene.geometry.mesh import Mesh
    from rgbd2scene.scene import folder as names

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    texture = getattr(mesh, "texture", None)
    write_ply(folder / names.MESH, Mesh(vertices=np.asarray(mesh.vertices, float), triangles=mesh.triangles,
                                        vertex_colors=getattr(mesh, "vertex_colors", None),
                                        uvs=getattr(mesh, "uvs", None)))
    if texture is not None:
        write_image(folder / names.TEXTURE, np.asarray(texture))
    if description is not None:
        tissue = description.objects[0].parts[0]
        tissue.material.texture = names.TEXTURE if texture is not None else None
    return folder


def render_base_colour(bpy, material: str, exr: Path) -> np.ndarray:
    """Linear RGB (H, W, 3) float64 of the open scene's left eye with ``material`` showing its own base colour,
    unlit (its Principled BSDF's Base Color input wired to an emission): what a material's detail computes,
    without light or shading. 16 samples, seed 0, written to the multilayer EXR ``exr`` and read back."""
    import OpenEXR

    nodes, links = bpy.data.materials[material].node_tree.nodes, bpy.data.materials[material].node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    emission = nodes.new("ShaderNodeEmission")
    links.new(bsdf.inputs["Base Color"].links[0].from_socket, emission.inputs["Color"])
    links.new(emission.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    scene = bpy.context.scene
    scene.render.use_multiview = False
    scene.cycles.samples, scene.cycles.seed = 16, 0
    settings = scene.render.image_settings
    settings.media_type, settings.file_format, settings.color_depth = ("MULTI_LAYER_IMAGE", "OPEN_EXR_MULTILAYER",
                                                                       "32")
    scene.render.filepath = str(exr)
    bpy.ops.render.render(write_still=True)
    with OpenEXR.File(str(exr), separate_channels=True) as f:
        channels = {k: np.array(c.pixels) for part in f.parts for k, c in part.channels.items()}
    return np.stack([channels[f"ViewLayer.Combined.{c}"] for c in "RGB"], axis=-1).astype(np.float64)


def flat_grid(z: float, half: float, n: int, grey: int = 150):
    """A fronto-parallel square grid mesh (n x n vertices, side 2 * half) at depth z, facing the camera at the
    origin, in one grey vertex colour."""
    from rgbd2scene.geometry.mesh import Mesh

    xs = np.linspace(-half, half, n)
    x, y = np.meshgrid(xs, xs)
    vertices = np.stack([x, y, np.full_like(x, z)], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return Mesh(vertices=vertices, triangles=tris.astype(np.int32), vertex_colors=np.full((n * n, 3), grey, np.uint8))
