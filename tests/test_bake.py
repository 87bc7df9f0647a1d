"""The wet-tissue detail baked into textures when the scene is built (render/materials.py): the texel size the
closest view needs, the seen UV window, and baked albedo against the procedural shader's own render."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytest.importorskip("OpenEXR")

from render.materials import DETAIL_UV, detail_texture_size, detail_uv_window, seen_vertices  # noqa: E402
from render.scene_builder import build_scene  # noqa: E402
from rgbd2scene.geometry.camera import Intrinsics  # noqa: E402
from rgbd2scene.scene.materials import TissueDetail  # noqa: E402
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object  # noqa: E402
from rgbd2scene.scene.paths import CameraPath  # noqa: E402
from rgbd2scene.scene.rig import StereoRig  # noqa: E402
from tests.conftest import render_base_colour, write_scene_files  # noqa: E402

TISSUE_RGB = (200, 110, 100)


def _plane(half_x: float, half_y: float, z: float, n: int = 8) -> SimpleNamespace:
    """A flat grid facing the camera at the origin (n x n vertices), UVs spanning [0, 1]^2, one colour."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    verts = np.stack([(2 * u - 1) * half_x, (1 - 2 * v) * half_y, np.full_like(u, z)], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    uvs = np.stack([u, 1 - v], -1).reshape(-1, 2).astype(np.float32)
    return SimpleNamespace(vertices=verts, triangles=tris.astype(np.int32), uvs=uvs,
                           vertex_colors=np.full((n * n, 3), 128, np.uint8),
                           texture=np.full((4, 4, 3), TISSUE_RGB, np.uint8))


def test_texture_size_follows_the_closest_pixel_and_the_window():
    plane = _plane(0.01, 0.005, 0.05)  # 2 x 1 cm
    full = (np.zeros(2), np.ones(2))
    # a pixel at 5 cm with fx 100 spans 0.5 mm: 40 x 20 texels, twice as many at 2 texels per pixel
    assert detail_texture_size(plane.vertices, plane.triangles, plane.uvs, full, 0.05, 100.0) == (40, 20)
    assert detail_texture_size(plane.vertices, plane.triangles, plane.uvs, full, 0.05, 100.0,
                               texels_per_pixel=2.0) == (80, 40)
    half = (np.array([0.25, 0.5]), np.array([0.75, 1.0]))
    assert detail_texture_size(plane.vertices, plane.triangles, plane.uvs, half, 0.05, 100.0) == (20, 10)
    assert detail_texture_size(plane.vertices, plane.triangles, plane.uvs, full, 0.05, 100.0, max_size=10) == (10, 5)
    flat_uvs = np.full_like(plane.uvs, 0.5)  # UVs that do not unfold the mesh: nothing to bake
    assert detail_texture_size(plane.vertices, plane.triangles, flat_uvs, full, 0.05, 100.0) is None


def test_seen_vertices_and_their_uv_window():
    plane = _plane(0.05, 0.05, 0.05, n=11)  # 10 x 10 cm, vertices every centimetre
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 15.5], [0, 0, 1]])
    eye = np.eye(4)
    seen, closest = seen_vertices(plane.vertices, [eye], K, 64, 32, margin=0.0)
    # 64 px at fx 50 spans 6.4 cm at 5 cm: |x| <= 3.2 cm -> 7 columns; 3.2 cm tall -> |y| <= 1.6 cm: 3 rows
    assert seen.sum() == 7 * 3 and closest == pytest.approx(0.05)
    lo, hi = detail_uv_window(plane.uvs, seen)
    np.testing.assert_allclose(lo, [0.2 - 0.012, 0.4 - 0.004], atol=1e-9)
    np.testing.assert_allclose(hi, [0.8 + 0.012, 0.6 + 0.004], atol=1e-9)
    behind = eye.copy()
    behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # looking away from the plane
    assert not seen_vertices(plane.vertices, [behind], K, 64, 32)[0].any()
    assert detail_uv_window(plane.uvs, np.zeros(len(plane.uvs), bool)) is None


def _albedo(detail: TissueDetail, folder) -> tuple[np.ndarray, object]:
    """Linear base colour the wet-tissue material gives a plane filling the view (192x96, left eye), and the
    material as built."""
    intr = Intrinsics.from_fov(192, 96, 70.0)
    desc = SceneDescription(StereoRig.parallel(intr, 0.004, clip_start=0.001, clip_end=1.0),
                            CameraPath(np.array([np.eye(4)]), fps=25.0, kind="test"), Light(power_w=0.05),
                            [tissue_object("wet_tissue", detail=detail)])
    build_scene(desc, write_scene_files(folder, _plane(0.06, 0.04, 0.05, n=16), desc))
    material = bpy.data.materials["wet_tissue"]
    return render_base_colour(bpy, "wet_tissue", folder / "albedo.exr"), material


def test_baked_detail_matches_the_procedural_shader(tmp_path):
    procedural, mat = _albedo(TissueDetail(bake=False), tmp_path / "procedural")
    assert any(n.type == "TEX_NOISE" for n in mat.node_tree.nodes)
    baked, mat = _albedo(TissueDetail(), tmp_path / "baked")
    images = [n.image for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.image.name.startswith("tissue")]
    assert not any(n.type == "TEX_NOISE" for n in mat.node_tree.nodes)  # nothing procedural left
    assert len(images) == 2 and all(img.packed_file is not None for img in images)
    assert DETAIL_UV in bpy.data.objects["Tissue"].data.uv_layers

    g_proc, g_baked = procedural[..., 1], baked[..., 1]
    corr = np.corrcoef(g_proc.ravel(), g_baked.ravel())[0, 1]
    mean_ratio = baked.reshape(-1, 3).mean(0) / procedural.reshape(-1, 3).mean(0)
    std_ratio = g_baked.std() / g_proc.std()
    print(f"baked vs procedural albedo: correlation {corr:.3f}, mean ratio {np.round(mean_ratio, 4)}, "
          f"std ratio {std_ratio:.3f}")
    assert np.all(np.abs(mean_ratio - 1.0) < 0.02)  # the same colour on average
    assert corr > 0.8  # the same pattern, in the same place (another seed or a shifted UV map: about 0)
    assert 0.8 < std_ratio < 1.2  # with about the same contrast
