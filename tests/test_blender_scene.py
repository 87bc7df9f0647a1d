"""The Blender scene: mesh, packed texture, camera path, stereo rig, exact K, light, colour round trip.

Renders are tiny (64x32 / 64x48, 1 sample, Cycles CPU). K is pinned with the Depth pass of a tilted
plane: Depth comes from the first sample through the pixel centre, so it must equal the analytic
ray-plane depth through (u - cx)/fx, (v - cy)/fy at every pixel, in both eyes.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
OpenEXR = pytest.importorskip("OpenEXR")
cv2 = pytest.importorskip("cv2")

from render.scene_builder import build_scene  # noqa: E402
from rgbd2scene import conventions as cv  # noqa: E402
from rgbd2scene.geometry.camera import Intrinsics  # noqa: E402
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object  # noqa: E402
from rgbd2scene.scene.paths import CameraPath, look_at  # noqa: E402
from rgbd2scene.scene.rig import StereoRig  # noqa: E402
from tests.conftest import write_scene_files  # noqa: E402

# non-centred principal point and fx != fy on purpose
INTR = Intrinsics(64, 32, 50.0, 44.0, 27.3, 18.6)
BASELINE = 0.005


# --- helpers -----------------------------------------------------------------------------------------

def grid_mesh(depth: np.ndarray, intr: Intrinsics, texture: np.ndarray) -> SimpleNamespace:
    """Organised grid mesh of a depth map, as the mesh module builds it (duck-typed Mesh)."""
    h, w = depth.shape
    idx = np.arange(h * w).reshape(h, w)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    u, v = cv.pixel_grid(h, w)
    uvs = np.stack([(u + 0.5) / w, 1.0 - (v + 0.5) / h], -1).reshape(-1, 2).astype(np.float32)
    return SimpleNamespace(vertices=cv.backproject(depth, intr.K).reshape(-1, 3),
                           triangles=tris.astype(np.int32), uvs=uvs, vertex_colors=texture.reshape(-1, 3),
                           texture=texture)


def plane_mesh(point, normal, half_size: float = 0.3) -> SimpleNamespace:
    """A big quad through ``point`` with unit ``normal``; its winding makes Blender's normal = ``normal``."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    e1 = np.cross(n, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    p = np.asarray(point, float)
    verts = np.array([p - e1 - e2, p + e1 - e2, p + e1 + e2, p - e1 + e2]) * 1.0
    verts = p + (verts - p) * half_size
    return SimpleNamespace(vertices=verts, triangles=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                           uvs=np.full((4, 2), 0.5, np.float32), vertex_colors=np.full((4, 3), 128, np.uint8),
                           texture=np.full((2, 2, 3), 128, np.uint8))


def describe(poses, intr: Intrinsics = INTR, material: str = "as_captured", light: Light | None = None):
    rig = StereoRig.parallel(intr, BASELINE, clip_start=0.001, clip_end=2.0)
    path = CameraPath(np.asarray(poses, float).reshape(-1, 4, 4), fps=25.0, kind="test")
    return SceneDescription(rig, path, light or Light(), [tissue_object(material)])


def build(description, mesh, folder: Path, blend: Path | None = None) -> None:
    """The scene of ``description`` with ``mesh`` as its tissue, built in this process."""
    build_scene(description, write_scene_files(folder, mesh, description), blend)


def render_eyes(out: Path, exr: bool = True, samples: int = 1) -> dict:
    """Render both eyes; EXR: {eye: {channel: (H,W) float32}}, PNG: {eye: (H,W,3) uint8 RGB}."""
    scene = bpy.context.scene
    scene.cycles.samples = samples
    scene.cycles.filter_width = 0.01  # sample the pixel centre
    scene.cycles.seed = 0
    settings = scene.render.image_settings
    if exr:
        scene.view_layers[0].use_pass_z = True
        settings.media_type = "MULTI_LAYER_IMAGE"
        settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"
    scene.render.filepath = str(out / "frame_")
    bpy.ops.render.render(write_still=True)
    result = {}
    for eye, suffix in (("left", "L"), ("right", "R")):
        if exr:
            with OpenEXR.File(str(out / f"frame__{suffix}.exr"), separate_channels=True) as f:
                result[eye] = {k: np.array(c.pixels) for part in f.parts for k, c in part.channels.items()}
        else:
            result[eye] = cv2.imread(str(out / f"frame__{suffix}.png"), cv2.IMREAD_COLOR)[..., ::-1]
    return result


def rotation_z(deg: float) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def wobbly_path(frames: int = 12) -> np.ndarray:
    """Moving, turning and rolling through more than 360 degrees (exercises quaternion hemispheres)."""
    poses = []
    for k in range(frames):
        t = k / (frames - 1)
        pos = [0.01 * math.cos(3 * t), 0.008 * math.sin(5 * t), -0.01 + 0.02 * t]
        target = [0.005 * math.sin(2 * t), 0.0, 0.06]
        poses.append(look_at(pos, target) @ rotation_z(400.0 * t))
    return np.array(poses)


def angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


# --- tests ---------------------------------------------------------------------------------------------

def test_tissue_mesh_faces_the_capture_camera(tmp_path):
    rng = np.random.default_rng(1)
    u, v = cv.pixel_grid(24, 32)
    depth = 0.05 + 0.0004 * u + 0.0002 * v + 0.002 * np.sin(u / 5.0)
    intr = Intrinsics.from_fov(32, 24, 70.0)
    mesh = grid_mesh(depth, intr, rng.integers(0, 256, (24, 32, 3), dtype=np.uint8))
    build(describe([np.eye(4)], intr), mesh, tmp_path)

    obj = bpy.data.objects["Tissue"]
    me = obj.data
    assert obj.pass_index == 1
    assert (len(me.vertices), len(me.polygons)) == (len(mesh.vertices), len(mesh.triangles))
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    assert np.allclose(co.reshape(-1, 3), mesh.vertices, atol=1e-8)

    normals, centres = np.empty(3 * len(me.polygons)), np.empty(3 * len(me.polygons))
    me.polygons.foreach_get("normal", normals)
    me.polygons.foreach_get("center", centres)
    normals, centres = normals.reshape(-1, 3), centres.reshape(-1, 3)
    assert np.all(np.sum(normals * centres, axis=1) < 0)  # towards the capture camera at the origin
    assert np.all(normals[:, 2] < -0.5)  # world -z

    loop_vertex = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", loop_vertex)
    assert np.array_equal(loop_vertex, mesh.triangles.ravel())
    loop_uv = np.empty(2 * len(me.loops), np.float32)
    me.uv_layers["UVMap"].uv.foreach_get("vector", loop_uv)
    assert np.array_equal(loop_uv.reshape(-1, 2), mesh.uvs[loop_vertex])
    smooth = np.empty(len(me.polygons), bool)
    me.polygons.foreach_get("use_smooth", smooth)
    assert smooth.all()
    assert not me.validate(verbose=False)  # nothing to repair


def test_blend_is_self_contained_and_self_describing(tmp_path):
    rng = np.random.default_rng(2)
    texture = rng.integers(0, 256, (12, 20, 3), dtype=np.uint8)
    intr = Intrinsics.from_fov(20, 12, 60.0)
    mesh = grid_mesh(np.full((12, 20), 0.05), intr, texture)
    desc = describe(wobbly_path(4), intr, "wet_tissue")
    blend = tmp_path / "scene" / "scene.blend"
    build(desc, mesh, blend.parent, blend)
    assert sorted(p.name for p in blend.parent.iterdir()) == ["mesh.ply", "mesh_texture.png", "scene.blend"]

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    image = bpy.data.images["Texture"]
    assert image.packed_file is not None
    assert image.colorspace_settings.name == "sRGB"
    w, h = image.size
    pixels = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(pixels)
    back = np.round(pixels.reshape(h, w, 4)[::-1, :, :3] * 255).astype(np.uint8)
    assert np.array_equal(back, texture)
    stored = json.loads(bpy.context.scene["rgbd2scene"])
    assert stored == json.loads(json.dumps(desc.to_dict()))
    assert bpy.data.objects["Tissue"].active_material.name == "wet_tissue"


def test_camera_and_light_follow_the_path(tmp_path):
    poses = wobbly_path(12)
    light = Light(kind="spot", power_w=0.3, spot_size_deg=90.0, offset=(0.002, -0.001, 0.0005), radius=0.0004)
    build(describe(poses, light=light), plane_mesh([0, 0, 0.06], [0, 0, -1]), tmp_path)
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (0, 11)
    assert math.isclose(scene.render.fps / scene.render.fps_base, 25.0)
    cam, lamp = bpy.data.objects["Endoscope"], bpy.data.objects["ScopeLight"]
    assert scene.camera == cam and lamp.parent == cam
    assert lamp.data.type == "SPOT" and math.isclose(lamp.data.energy, 0.3, rel_tol=1e-6)
    assert math.isclose(lamp.data.spot_size, math.radians(90.0), rel_tol=1e-6)
    assert math.isclose(lamp.data.shadow_soft_size, 0.0004, rel_tol=1e-6)

    offset = np.array([*light.offset, 1.0])
    pose_err = light_err = 0.0
    for k, T in enumerate(poses):
        scene.frame_set(k)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        M = np.array(cam.evaluated_get(depsgraph).matrix_world)
        pose_err = max(pose_err, np.abs(M - cv.blender_pose_from_opencv(T)).max())
        L = np.array(lamp.evaluated_get(depsgraph).matrix_world)
        light_err = max(light_err, np.abs(L[:3, 3] - (T @ offset)[:3]).max(),
                        np.abs(-L[:3, 2] - T[:3, 2]).max())  # the spot shines along the view
    print(f"pose error {pose_err:.2e}, light error {light_err:.2e}")
    assert pose_err < 1e-6, pose_err
    assert light_err < 1e-6, light_err

    # no flips between keys: halfway, the rotation lies between its neighbours
    for k in range(len(poses) - 1):
        scene.frame_set(k, subframe=0.5)
        R = np.array(cam.matrix_world)[:3, :3] @ np.diag([1.0, -1.0, -1.0])
        step = angle_deg(poses[k][:3, :3], poses[k + 1][:3, :3])
        assert angle_deg(R, poses[k][:3, :3]) <= 0.5 * step + 0.1


def test_stereo_rig_and_render_defaults(tmp_path):
    build(describe([np.eye(4)]), plane_mesh([0, 0, 0.06], [0, 0, -1]), tmp_path)
    scene, cam = bpy.context.scene, bpy.data.objects["Endoscope"].data
    assert scene.render.use_multiview and scene.render.views_format == "STEREO_3D"
    assert [v.name for v in scene.render.views if v.use] == ["left", "right"]
    assert cam.stereo.convergence_mode == "PARALLEL" and cam.stereo.pivot == "LEFT"
    assert math.isclose(cam.stereo.interocular_distance, BASELINE, rel_tol=1e-6)
    assert math.isclose(cam.clip_start, 0.001, rel_tol=1e-6) and math.isclose(cam.clip_end, 2.0, rel_tol=1e-6)
    render = scene.render
    assert (render.resolution_x, render.resolution_y, render.resolution_percentage) == (64, 32, 100)
    assert scene.render.engine == "CYCLES" and scene.cycles.device == "CPU" and scene.cycles.samples == 16
    assert not scene.render.film_transparent and not scene.render.use_motion_blur
    assert scene.view_settings.view_transform == "Standard" and scene.view_settings.look == "None"
    background = scene.world.node_tree.nodes["Background"]
    assert background.inputs["Strength"].default_value == 0.0


@pytest.mark.parametrize("intr", [INTR, Intrinsics(24, 40, 30.0, 36.0, 13.2, 17.9)],
                         ids=["fx>fy", "portrait-fy>fx"])
def test_intrinsics_exact_in_both_eyes(tmp_path, intr):
    """Depth of a tilted plane at every pixel centre equals the analytic value from K, left and right.

    (The multilayer EXR with fx != fy only writes because build_scene sets ``use_exr_interleave``.)
    """
    T_left = look_at([0.006, -0.004, -0.01], [0.002, 0.003, 0.06]) @ rotation_z(25.0)
    point, normal = np.array([0.0, 0.0, 0.06]), np.array([0.45, -0.3, -1.0])
    normal /= np.linalg.norm(normal)
    build(describe([T_left], intr), plane_mesh(point, normal), tmp_path / "scene")
    out = render_eyes(tmp_path)

    rig = StereoRig.parallel(intr, BASELINE)
    rays = cv.pixel_rays(intr.height, intr.width, intr.K)
    for eye, T in (("left", T_left), ("right", rig.right_pose(T_left))):
        n_cam = T[:3, :3].T @ normal
        expected = (normal @ (point - T[:3, 3])) / (rays @ n_cam)
        depth = out[eye]["ViewLayer.Depth.Z"].astype(np.float64)
        err = np.abs(depth - expected)
        dz_dv, dz_du = np.gradient(expected)
        px_equiv = err / np.hypot(dz_du, dz_dv)  # the K error (px) that would explain this depth error
        assert err.max() < 2e-7, (eye, err.max())
        assert px_equiv.max() < 1e-3, (eye, px_equiv.max())
        print(f"{eye}: max depth error {err.max() * 1e9:.1f} nm, {px_equiv.max():.2e} px equivalent")


@pytest.mark.parametrize("source", ["texture", "vertex_colors"])
def test_as_captured_round_trip_reproduces_texture(tmp_path, source):
    """Rendered from the capture camera, the 'as_captured' scene gives back the captured colours."""
    intr = Intrinsics(64, 48, 55.0, 52.0, 30.2, 24.7)
    u, v = cv.pixel_grid(48, 64)
    depth = 0.05 + 0.0003 * u - 0.0002 * v
    texture = np.random.default_rng(3).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    mesh = grid_mesh(depth, intr, texture)
    if source == "vertex_colors":
        mesh.texture = None
    build(describe([np.eye(4)], intr, "as_captured"), mesh, tmp_path / "scene")
    assert len(bpy.data.images) == (source == "texture")
    left = render_eyes(tmp_path, exr=False)["left"]
    err = np.abs(left.astype(int) - texture.astype(int))[1:-1, 1:-1]  # the border pixels lie on mesh edges
    exact = np.mean(err.max(-1) == 0)
    print(f"round trip ({source}): mean abs error {err.mean():.3f}/255, {100 * exact:.2f} % of pixels exact")
    assert err.mean() < 2.0
    # Pixel-centre rays pass exactly through the vertices here; Cycles misses a few such rays (pinholes)
    assert exact > 0.99


def test_wet_tissue_is_lit_by_the_scope_light(tmp_path):
    build(describe([np.eye(4)], material="wet_tissue"), plane_mesh([0, 0, 0.05], [0, 0, -1]), tmp_path / "scene")
    bpy.data.images["Texture"].pixels.foreach_set(np.tile([0.8, 0.4, 0.35, 1.0], 4).astype(np.float32))
    left = render_eyes(tmp_path, exr=False, samples=4)["left"].astype(float)
    assert left.mean() > 10  # the light reaches the tissue: the image is not black
    bpy.data.objects["ScopeLight"].data.energy = 0.0
    dark = render_eyes(tmp_path, exr=False, samples=4)["left"]
    assert dark.max() == 0  # no other light


def test_deformation_shape_keys_are_the_numpy_formula(tmp_path):
    """Blender's shape-key mix of the tissue at every frame is :meth:`Deformation.displace` of the rest mesh."""
    from rgbd2scene.scene.deformation import Deformation, rest_normals

    u, v = cv.pixel_grid(12, 16)
    intr = Intrinsics.from_fov(16, 12, 60.0)
    mesh = grid_mesh(0.05 + 0.002 * np.sin(u / 3.0) * np.cos(v / 4.0), intr, np.full((12, 16, 3), 128, np.uint8))
    desc = describe(wobbly_path(6), intr)
    deformation = Deformation.preset("heartbeat", centre=tuple(mesh.vertices.mean(axis=0)), amplitude_m=0.001)
    desc.objects[0].parts[0].deformation = deformation
    build(desc, mesh, tmp_path)
    rest = np.asarray(mesh.vertices, np.float32).astype(np.float64)  # what the PLY holds
    normals = rest_normals(rest, mesh.triangles)
    obj = bpy.data.objects["Tissue"]
    moved = 0.0
    for f in range(6):
        bpy.context.scene.frame_set(f)
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
        co = np.empty(3 * len(evaluated.vertices), np.float32)
        evaluated.vertices.foreach_get("co", co)
        obj.to_mesh_clear()
        expected = deformation.displace(rest, normals, desc.time(f))
        assert np.abs(co.reshape(-1, 3) - expected).max() < 2e-8  # float32 at 5 cm: a few nm
        moved = max(moved, np.abs(expected - rest).max())
    assert moved > 2e-4  # it does move (sub-millimetre)
