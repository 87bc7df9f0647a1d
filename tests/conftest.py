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
