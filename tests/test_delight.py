"""De-lighting a scope capture's texture (``rgbd2scene.scene.delight``, ``scene --delight``)."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd2scene.reconstruct.mesh import grid_mesh
from rgbd2scene.scene.delight import DELIGHT_SMOOTH_PX, MAX_GAIN, delight_texture, spot_mask
from rgbd2scene.scene.model import Light
from rgbd2scene.sensor.tone import srgb_decode, srgb_encode
from rgbd2scene.stages.scene import SceneOptions, delight_choice

W, H, F = 120, 90, 100.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1]])


def _tilted_plane() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth (H, W) of the plane n . X = d seen from the camera at the origin, its points and its unit normal."""
    n = np.array([0.35, -0.15, -1.0])
    n /= np.linalg.norm(n)  # facing the camera (n . z < 0), tilted about 21 degrees
    d = -0.03  # 3 cm from the camera along the normal: near, so 1/r^2 varies a lot over the view
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], axis=-1)
    z = d / (rays @ n)
    return z, rays * z[..., None], n


def _albedo_pattern() -> np.ndarray:
    """Linear albedo (H, W, 3): stripes and a gradient, 0.1-0.5 (no clipping after the level is restored)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    base = 0.3 + 0.12 * np.sin(u / 6.0) * np.cos(v / 9.0)
    return np.stack([base, 0.8 * base, 0.5 * base + 0.05 * u / W], axis=-1)


def test_delight_recovers_the_albedo_of_a_plane_lit_by_a_point_light_at_the_camera():
    z, points, normal = _tilted_plane()
    albedo = _albedo_pattern()
    # the capture: irradiance of a point light at the camera, cos(incidence) / r^2, computed here independently
    to_light = -points
    r2 = np.sum(to_light ** 2, axis=-1)
    cos_in = (to_light @ normal) / np.sqrt(r2)
    shading = cos_in / r2
    shading /= shading.max()
    lit = albedo * shading[..., None] * 1.6  # the capture exposure: bright near the camera, darker far away
    assert lit.max() <= 1.0
    texture = np.rint(srgb_encode(lit) * 255).astype(np.uint8)
    mesh, _ = grid_mesh(z.astype(np.float32), K, texture, max_relative_jump=None)
    light = Light(kind="point", offset=(0.0, 0.0, 0.0), outlets=1)
    out, stats = delight_texture(texture, mesh.vertices, mesh.triangles, mesh.uvs, light)
    recovered = srgb_decode(out / 255.0)
    inner = (slice(2, H - 2), slice(2, W - 2))  # away from the border, whose normals see one side only
    ratio = recovered[inner] / albedo[inner]
    # recovered up to one level: the ratio is constant (8-bit quantisation on both ends: about 1 % at 0.03)
    spread = np.std(ratio) / np.mean(ratio)
    assert spread < 0.01, spread
    # the level: the median texel keeps its value
    gain = recovered / srgb_decode(texture / 255.0)
    assert np.median(gain) == pytest.approx(1.0, abs=0.01)
    assert stats["clamped_share"] < 0.005 and stats["clipped_share"] == 0  # one far corner reaches the clamp
    # the test can fail: without the cosine, or without the inverse square, the spread is far larger
    for wrong in (1.0 / r2, cos_in):
        wrong_ratio = (lit / wrong[..., None])[inner] / albedo[inner]
        assert np.std(wrong_ratio) / np.mean(wrong_ratio) > 5 * 0.01


def test_smoothing_keeps_the_depths_pixel_noise_out_of_the_albedo():
    """The capture is lit on the true plane; the mesh comes from depth with pixel-scale noise (as stereo depth
    has). Per vertex, the noisy normals' shading goes into the albedo; smoothed over 5 texels it stays out."""
    z, points, normal = _tilted_plane()
    albedo = _albedo_pattern()
    to_light = -points
    r2 = np.sum(to_light ** 2, axis=-1)
    shading = (to_light @ normal) / np.sqrt(r2) / r2
    lit = albedo * (shading / shading.max())[..., None] * 1.6
    texture = np.rint(srgb_encode(lit) * 255).astype(np.uint8)
    noisy = z * (1 + 0.002 * np.random.default_rng(0).standard_normal(z.shape))  # 0.06 mm at 3 cm
    mesh, _ = grid_mesh(noisy.astype(np.float32), K, texture, max_relative_jump=None)
    light = Light(kind="point", offset=(0.0, 0.0, 0.0), outlets=1)
    spread = {}
    for sigma in (0.0, DELIGHT_SMOOTH_PX):
        out, _ = delight_texture(texture, mesh.vertices, mesh.triangles, mesh.uvs, light, smooth_px=sigma)
        ratio = (srgb_decode(out / 255.0) / albedo)[8:-8, 8:-8]
        spread[sigma] = np.std(ratio) / np.mean(ratio)
    assert spread[DELIGHT_SMOOTH_PX] < 0.02 and spread[0.0] > 0.04, spread


def test_two_outlets_beside_the_lenses_are_summed():
    """The light of a stereo scope: two outlets, each with its own distance and incidence."""
    z, points, normal = _tilted_plane()
    albedo = _albedo_pattern()
    light = Light(kind="point", offset=(0.0025, 0.0, 0.0), outlets=2, outlet_spacing=0.008)
    shading = np.zeros((H, W))
    for offset in light.outlet_offsets():
        to_light = np.asarray(offset) - points
        r2 = np.sum(to_light ** 2, axis=-1)
        shading += np.maximum(to_light @ normal, 0) / np.sqrt(r2) / r2
    lit = albedo * (shading / shading.max())[..., None] * 1.6
    texture = np.rint(srgb_encode(lit) * 255).astype(np.uint8)
    mesh, _ = grid_mesh(z.astype(np.float32), K, texture, max_relative_jump=None)
    out, _ = delight_texture(texture, mesh.vertices, mesh.triangles, mesh.uvs, light)
    ratio = (srgb_decode(out / 255.0) / albedo)[2:-2, 2:-2]
    assert np.std(ratio) / np.mean(ratio) < 0.01


def test_gain_is_clamped_where_the_light_barely_reaches():
    """A spot whose cone ends inside the view: beyond it the gain stops at MAX_GAIN, the texels stay finite."""
    z, points, _ = _tilted_plane()
    texture = np.full((H, W, 3), 120, np.uint8)
    mesh, _ = grid_mesh(z.astype(np.float32), K, texture, max_relative_jump=None)
    light = Light(kind="spot", spot_size_deg=40.0, offset=(0.0, 0.0, 0.0), outlets=1)
    out, stats = delight_texture(texture, mesh.vertices, mesh.triangles, mesh.uvs, light)
    linear = srgb_decode(out / 255.0)[..., 0]
    before = srgb_decode(120 / 255.0)
    assert stats["clamped_share"] > 0.2
    assert linear.max() == pytest.approx(MAX_GAIN * before, rel=0.02) and linear.min() > 0


def test_spot_mask_is_blenders_cone():
    half = np.radians(50.0)
    edge = np.cos(half)
    full = edge + (1 - edge) * 0.5  # blend 0.5: full strength from here to the axis
    np.testing.assert_allclose(spot_mask(np.array([1.0, full, edge, edge - 0.1]), 100.0), [1, 1, 0, 0])
    assert spot_mask(np.array([(edge + full) / 2]), 100.0)[0] == pytest.approx(0.5)


def test_auto_delights_scope_lit_captures_only():
    stereo = {"capture": {"stereo": {"calibration_values": {}}}}
    rgbd = {"capture": {"intrinsics": {}}}
    assert delight_choice(stereo, SceneOptions(), True)[0]
    assert not delight_choice(rgbd, SceneOptions(), True)[0]
    assert delight_choice(rgbd, SceneOptions(delight="on"), True)[0]
    assert not delight_choice(stereo, SceneOptions(delight="off"), True)[0]
    assert not delight_choice(stereo, SceneOptions(material="as_captured"), True)[0]  # the render adds no light
    assert not delight_choice(stereo, SceneOptions(delight="on"), False)[0]


def _render_plane_row(out, d: float, size: int = 201, scale: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Middle row (x metres, linear radiance) of a white Lambertian plane ``d`` metres before one spot outlet at
    the camera, set up by ``render.scene_builder.add_scope_light``, seen by an orthographic camera."""
    bpy = pytest.importorskip("bpy")
    from render.scene_builder import add_scope_light

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.use_denoising, scene.cycles.max_bounces = 64, False, 0
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.world = bpy.data.worlds.new("World")
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0, 0, -d))
    material = bpy.data.materials.new("White")
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (1, 1, 1, 1)
    bsdf.inputs["Roughness"].default_value = 1.0
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    bpy.context.object.data.materials.append(material)
    camera_data = bpy.data.cameras.new("Camera")
    camera_data.type, camera_data.ortho_scale, camera_data.clip_start = "ORTHO", scale, 0.001
    camera = bpy.data.objects.new("Camera", camera_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    add_scope_light(camera, Light(kind="spot", power_w=1.0, offset=(0.0, 0.0, 0.0), outlets=1))
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(out / "plane.exr")
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(out / "plane.exr"))
    row = np.array(image.pixels[:]).reshape(size, size, 4)[size // 2, :, 0]
    return (np.arange(size) - size // 2) * scale / size, row


def test_the_light_model_is_blenders(tmp_path):
    """Blender's radiance across a white Lambertian plane 2 cm before the scope light (as the render sets it
    up) is spot_mask x cos / r^2, the de-lighting's model, inside the cone and across its edge."""
    d = 0.02
    x, radiance = _render_plane_row(tmp_path, d)
    cos_axis = d / np.hypot(x, d)
    model = spot_mask(cos_axis, Light().spot_size_deg) * cos_axis ** 3 / d ** 2  # cos(incidence) / r^2
    scale = radiance[len(x) // 2] / model[len(x) // 2]
    lit = model > 0.05 * model.max()
    # 3 %: a pixel averages 0.5 mm of the plane, across the cone's steep edge too
    np.testing.assert_allclose(radiance[lit] / scale, model[lit], rtol=0.03)
    inner = cos_axis > 0.85  # within 32 degrees: the cone is full, the fall-off is cos / r^2 alone
    np.testing.assert_allclose(radiance[inner] / scale, model[inner], rtol=0.005)
    outside = cos_axis < np.cos(np.radians(50.0))  # beyond the cone's half angle: dark (the outlet's 0.5 mm
    assert radiance[outside].max() < 1e-3 * radiance.max()  # radius lets a trace past the edge)


def test_a_de_lit_scene_folder_reused_as_a_mesh_folder_starts_from_the_lit_texture(tmp_path):
    """``scene --mesh-dir`` of a scene whose texture was de-lit: the new scene gets the lit texture back (to de-light
    again with its own light, or to keep), never the albedo de-lit a second time."""
    from rgbd2scene.files.images import read_image, write_image
    from rgbd2scene.files.meshio import write_ply
    from rgbd2scene.scene import folder
    from rgbd2scene.stages.scene import load_mesh_folder

    z, _, _ = _tilted_plane()
    lit = np.full((H, W, 3), 90, np.uint8)
    mesh, _ = grid_mesh(z.astype(np.float32), K, lit, max_relative_jump=None)
    src, out = tmp_path / "scene", tmp_path / "rebuilt"
    src.mkdir(), out.mkdir()
    write_ply(src / folder.MESH, mesh)
    write_image(src / folder.TEXTURE, np.full((H, W, 3), 200, np.uint8))  # the albedo
    write_image(src / folder.TEXTURE_LIT, lit)
    (src / folder.SCENE_JSON).write_text('{"delight": {"applied": true}, "files": {"texture_lit": "texture_lit.png"}}')
    loaded, record = load_mesh_folder(src, out)
    np.testing.assert_array_equal(loaded.texture, lit)
    np.testing.assert_array_equal(read_image(out / folder.TEXTURE), lit)
    np.testing.assert_array_equal(read_image(src / folder.TEXTURE), 200)  # the source folder is untouched
    assert "delight" not in record and "texture_lit" not in record["files"]
