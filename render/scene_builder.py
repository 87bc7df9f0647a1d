"""Build the Blender scene of a :class:`~rgbd2scene.scene.SceneDescription`: textured tissue mesh, stereo
endoscope on its path, light at the tip.

Blender-side conventions (the project's contract is OpenCV; see ``rgbd2scene.conventions``):

* **Poses.** The camera object "Endoscope" is the LEFT eye. Its ``matrix_world`` is
  ``T_world_cam @ diag(1, -1, -1, 1)`` (Blender cameras look down -Z with +Y up), always assigned as a
  ``mathutils.Matrix``. The path is keyed on every integer frame 0..F-1 (location + quaternion, linear
  interpolation, quaternions kept in one hemisphere so no key flips).
* **Intrinsics K** (see :func:`set_intrinsics`). ``sensor_fit = 'HORIZONTAL'`` so one pixel column is
  ``sensor_width / lens / W`` wide at unit distance: ``lens = fx * sensor_width / W``. ``fy != fx`` uses
  the pixel aspect: a row is ``pixel_aspect_y / pixel_aspect_x`` columns high, so
  ``pixel_aspect_y / pixel_aspect_x = fx / fy`` (the smaller of the two is 1, as Blender wants >= 1).
  Blender's principal point at zero shift is the image centre, pixel-centre coordinates ((W-1)/2, (H-1)/2),
  and both shifts are in units of W (the horizontally fitted dimension), with +y up:
  ``shift_x = ((W-1)/2 - cx) / W`` and ``shift_y = (cy - (H-1)/2) * (fx/fy) / W``.
  Resolution is W x H at 100 %. This pins K to float32 precision (checked in
  ``tests/test_blender_scene.py`` with the Depth pass of a tilted plane, both eyes).
* **Stereo.** ``render.use_multiview`` with ``views_format = 'STEREO_3D'`` (views "left"/"right", files
  suffixed ``_L``/``_R``); ``camera.data.stereo``: ``convergence_mode = 'PARALLEL'``, ``pivot = 'LEFT'``,
  ``interocular_distance = baseline``: the left view is the camera itself and the right view is it
  translated by +baseline along its x axis, with the same K (PARALLEL applies no shift; OFFAXIS would).
* **Light.** "ScopeLight" is parented to the camera at ``Light.offset`` (OpenCV camera frame, so
  ``(x, -y, -z)`` in Blender's camera frame), pointing down the camera's -Z (the view); with two outlets
  "ScopeLight" and "ScopeLight_2" sit beside the lenses (``Light.outlet_offsets``), half the power each.
  Energy in watts, Blender's inverse-square falloff, ``shadow_soft_size = radius``. The world is black
  (strength 0) unless an ambient strength is asked for, so the scope light is the only light.
* **Colour.** View transform 'Standard', look None, exposure 0, gamma 1, display sRGB, dither 0: with the
  "as_captured" material (Emission strength 1 from the sRGB texture) an 8-bit render from the capture
  camera reproduces the texture bytes. The materials' node graphs are in ``render.materials``.
* **Ids.** The tissue object's ``pass_index`` is its instance id (1), for the IndexOB pass.
* The scene's custom property ``scene["rgbd2scene"]`` holds the description as JSON.

Blender 5.0.1 behaviours this relies on or works around (measured):

* A multi-part multilayer EXR with any pass besides Combined fails to write when the pixel aspect is not 1
  (fx != fy), so ``image_settings.use_exr_interleave = True`` (one part, same channel names).
* Setting an image's colour space regenerates a generated image's buffer: set it before the pixels.
* Pixel-centre rays that pass exactly through a mesh vertex (rendering the capture view of a grid mesh)
  miss now and then (about 1 pixel in 1500): pinholes, background in every pass.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix
from scipy.spatial.transform import Rotation

from render.materials import (
    VERTEX_COLORS,
    bake_tissue_detail,
    detail_texture_size,
    detail_uv_window,
    make_material,
    seen_vertices,
    use_metric_texture_space,
)
from rgbd2scene.conventions import blender_pose_from_opencv
from rgbd2scene.files.atomic import atomic_path
from rgbd2scene.files.images import read_image
from rgbd2scene.files.meshio import read_ply
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.scene.deformation import Deformation, rest_normals
from rgbd2scene.scene.model import SPOT_BLEND, Light, SceneDescription, SceneObject
from rgbd2scene.scene.paths import CameraPath

TISSUE = "Tissue"
CAMERA = "Endoscope"
LIGHT = "ScopeLight"
TEXTURE = "Texture"
SCENE_PROPERTY = "rgbd2scene"


def build_scene(description: SceneDescription, scene_dir: str | Path, blend_path: str | Path | None = None, *,
                samples: int = 16, ambient: float = 0.0) -> None:
    """Reset Blender to an empty scene, build ``description`` and save it to ``blend_path``.

    Every object is built by its kind's builder (:data:`BUILDERS`) from the files the model names in
    ``scene_dir`` (geometry PLYs, textures), and every part is keyed on every frame from the model's
    poses, like the camera. ``ambient`` is the strength of a uniform white world light (0: the scope
    light is the only light). The .blend is written atomically and is self-contained (textures packed).
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    _render_defaults(scene, samples)
    for obj in description.objects:
        builder = BUILDERS.get(obj.kind)
        if builder is None:
            raise ValueError(f"object {obj.name!r}: no Blender builder for kind {obj.kind!r} "
                             f"(known: {', '.join(sorted(BUILDERS))})")
        builder(scene, obj, Path(scene_dir), description)

    camera = add_stereo_camera(scene, description.rig.intrinsics, description.rig.baseline,
                               description.rig.clip_start, description.rig.clip_end)
    animate_camera(scene, camera, description.path)
    add_scope_light(camera, description.light)
    set_world(scene, ambient)
    scene[SCENE_PROPERTY] = json.dumps(description.to_dict(), default=_json_default)
    scene.frame_set(0)
    if blend_path is not None:
        save_blend(blend_path)


# --- objects: one builder per kind ---------------------------------------------------------------------

def build_mesh_object(scene, obj: SceneObject, scene_dir: Path, description: SceneDescription) -> list:
    """Each part: its geometry file, its material (texture or vertex colours), its instance id as
    ``pass_index``, keyed on its poses and its deformation. The tissue's single part is the object "Tissue"."""
    made = []
    for part in obj.parts:
        mesh = read_ply(scene_dir / part.geometry)
        image = image_file = None
        if part.material.texture and mesh.uvs is not None:
            image_file = read_image(scene_dir / part.material.texture)
            if image_file is None:
                raise ValueError(f"{scene_dir / part.material.texture}: missing or unreadable texture")
        tissue = obj.kind == "tissue" and len(obj.parts) == 1
        name = TISSUE if tissue else f"{obj.name}.{part.name}"
        if image_file is not None:
            image = add_texture(image_file, name=TEXTURE if tissue else f"{name}.texture")
        material = make_material(part.material, image, mesh.vertex_colors is not None)
        bobj = add_tissue(mesh, material, part.id, name=name)
        if part.material.detail is not None and part.material.detail.enabled:
            use_metric_texture_space(bobj.data)  # the micro-structure is sized in metres on the surface
            bake_detail(bobj, part, mesh, image, description)
        if part.poses is not None:
            key_poses(scene, bobj, part.poses)
        if part.deformation is not None:
            key_deformation(bobj, mesh, part.deformation, description.path.frames, description.path.fps)
        made.append(bobj)
    return made


def bake_detail(bobj, part, mesh, image, description: SceneDescription) -> None:
    """Replace the wet-tissue material's procedural detail by textures baked over what the path can see, at the
    texel size its closest camera position needs (``render.materials``; kept procedural without usable UVs,
    with nothing in view or with ``bake`` off)."""
    if part.material.kind != "wet_tissue" or not part.material.detail.bake or mesh.uvs is None:
        return
    intr = description.rig.intrinsics
    # camera poses in the part's frame (the texture space is the undeformed mesh's)
    poses = [np.linalg.inv(part.pose_at(f)) @ description.camera_pose(f) for f in range(description.path.frames)]
    seen, closest = seen_vertices(mesh.vertices, poses, intr.K, intr.width, intr.height)
    window = detail_uv_window(mesh.uvs, seen)
    size = None if window is None else detail_texture_size(mesh.vertices, mesh.triangles, mesh.uvs, window,
                                                            closest, intr.fx)
    if size is None:
        return
    procedural = bobj.data.materials[0]
    baked = bake_tissue_detail(bobj, part.material.detail, size, window)
    bobj.data.materials[0] = material = make_material(part.material, image, mesh.vertex_colors is not None, baked)
    name = procedural.name
    bpy.data.materials.remove(procedural)
    material.name = name


def key_deformation(bobj, mesh, deformation: Deformation, frames: int, fps: float) -> None:
    """The deformation as shape keys: one per basis field B_k (``rest + n B_k``), its value c_k(f / fps)
    keyed on every frame f (linear), so Blender's mix ``rest + sum_k c_k (key_k - rest)`` is the formula
    of :mod:`rgbd2scene.scene.deformation` and the Vector pass sees the surface's own motion."""
    rest = np.asarray(mesh.vertices, dtype=np.float64)
    normals = rest_normals(rest, mesh.triangles)
    fields = deformation.basis(rest)
    coefficients = deformation.coefficients(np.arange(frames) / fps).reshape(len(fields), -1)
    bobj.shape_key_add(name="Basis", from_mix=False)
    frame_numbers = np.arange(frames, dtype=np.float64)
    action = bpy.data.actions.new(f"{bobj.name}Deformation")
    keys = bobj.data.shape_keys
    keys.animation_data_create()
    keys.animation_data.action = action
    for k, field_k in enumerate(fields):
        block = bobj.shape_key_add(name=f"deform_{k}", from_mix=False)
        block.slider_min, block.slider_max = -10.0, 10.0
        block.data.foreach_set("co", (rest + normals * field_k[:, None]).astype(np.float32).ravel())
        fcurve = action.fcurve_ensure_for_datablock(keys, f'key_blocks["{block.name}"].value')
        fcurve.keyframe_points.add(frames)
        fcurve.keyframe_points.foreach_set("co", np.stack([frame_numbers, coefficients[k]], 1).ravel())
        for key in fcurve.keyframe_points:
            key.interpolation = "LINEAR"
        fcurve.update()


#: Object kind (``SceneObject.kind``) -> the function that builds it into the scene.
BUILDERS = {"tissue": build_mesh_object, "mesh": build_mesh_object, "instrument": build_mesh_object}


# --- render settings -------------------------------------------------------------------------------

def _render_defaults(scene, samples: int) -> None:
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False  # a denoiser repaints texture detail; the renderer may opt in
    scene.render.film_transparent = False
    scene.render.use_motion_blur = False
    scene.render.dither_intensity = 0.0  # dithering would add noise to 8-bit output
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    # Blender 5.0.1 fails to write multi-part multilayer EXRs with any pass besides Combined when the
    # pixel aspect is not 1 (fx != fy: "Conflicting attributes ... 'pixelAspectRatio'"); the single-part
    # (interleaved) layout writes the same channel names and works.
    scene.render.image_settings.use_exr_interleave = True
    scene.display_settings.display_device = "sRGB"
    view = scene.view_settings
    view.view_transform = "Standard"
    view.look = "None"
    view.exposure = 0.0
    view.gamma = 1.0


def set_intrinsics(scene, camera, intrinsics: Intrinsics) -> None:
    """Make ``camera`` (object or camera data) render exactly ``intrinsics`` (OpenCV K, W x H)."""
    cam = camera.data if hasattr(camera, "data") else camera
    w, h = intrinsics.width, intrinsics.height
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100
    # a row is pixel_aspect_y / pixel_aspect_x columns high, i.e. fx / fy; Blender wants both >= 1
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = (1.0, fx / fy) if fx >= fy else (fy / fx, 1.0)
    cam.type = "PERSP"
    cam.lens_unit = "MILLIMETERS"
    cam.sensor_fit = "HORIZONTAL"
    cam.sensor_width = 36.0
    cam.sensor_height = 36.0 * h / w  # display only: the fit is horizontal
    cam.lens = fx * cam.sensor_width / w
    cam.shift_x = ((w - 1) / 2.0 - cx) / w
    cam.shift_y = (cy - (h - 1) / 2.0) * (fx / fy) / w


# --- tissue: texture, material, mesh ---------------------------------------------------------------

def add_texture(texture: np.ndarray, name: str = TEXTURE):
    """An sRGB image datablock with the RGB uint8 ``texture`` (rows top first), packed into the .blend."""
    tex = np.asarray(texture)
    if tex.dtype != np.uint8 or tex.ndim != 3 or tex.shape[2] != 3:
        raise ValueError(f"texture must be uint8 (H, W, 3), got {tex.dtype} {tex.shape}")
    h, w = tex.shape[:2]
    image = bpy.data.images.new(name, w, h, alpha=False)
    # set the colour space BEFORE the pixels: changing it regenerates a generated image's buffer
    image.colorspace_settings.name = "sRGB"
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = tex[::-1] / np.float32(255.0)  # Blender stores rows bottom first
    image.pixels.foreach_set(rgba.ravel())
    image.pack()  # encodes the byte buffer as PNG inside the .blend
    if image.packed_file is None:
        raise RuntimeError("Blender did not pack the texture")
    return image


def add_tissue(mesh, material, pass_index: int = 1, name: str = TISSUE):
    """Mesh object from the arrays (foreach_set, no from_pydata), UVs, vertex colours, smooth shading."""
    verts = np.ascontiguousarray(mesh.vertices, dtype=np.float32).reshape(-1, 3)
    tris = np.ascontiguousarray(mesh.triangles, dtype=np.int32).reshape(-1, 3)
    n, m = len(verts), len(tris)
    uvs, colors = getattr(mesh, "uvs", None), getattr(mesh, "vertex_colors", None)
    for what, array in (("uvs", uvs), ("vertex_colors", colors)):
        if array is not None and len(array) != n:
            raise ValueError(f"mesh has {n} vertices but {len(array)} {what}")
    me = bpy.data.meshes.new(name)
    me.vertices.add(n)
    me.attributes["position"].data.foreach_set("vector", verts.ravel())  # = vertices "co", 5x faster
    me.loops.add(3 * m)
    me.attributes[".corner_vert"].data.foreach_set("value", tris.ravel())  # = loops "vertex_index", 10x
    me.polygons.add(m)
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * m, 3, dtype=np.int32))  # sizes follow from starts
    me.update(calc_edges=True)  # most of the time (~0.4 s for 600k triangles)
    if uvs is not None:  # per-corner UVs = the UV of the corner's vertex
        uv_corner = np.asarray(uvs, dtype=np.float32).reshape(-1, 2)[tris.ravel()]
        me.uv_layers.new(name="UVMap").uv.foreach_set("vector", uv_corner.ravel())
    if colors is not None:  # sRGB bytes, per vertex
        rgba = np.ones((n, 4), np.float32)
        rgba[:, :3] = np.asarray(colors, dtype=np.float32).reshape(-1, 3) / 255.0
        attribute = me.color_attributes.new(VERTEX_COLORS, "BYTE_COLOR", "POINT")
        attribute.data.foreach_set("color_srgb", rgba.ravel())
    me.shade_smooth()
    me.materials.append(material)
    obj = bpy.data.objects.new(name, me)
    obj.pass_index = pass_index
    bpy.context.scene.collection.objects.link(obj)
    return obj


# --- stereo endoscope on its path, light at the tip ------------------------------------------------

def add_stereo_camera(scene, intrinsics: Intrinsics, baseline: float, clip_start: float, clip_end: float,
                      name: str = CAMERA):
    """The left eye as the scene camera, with a rectified (PARALLEL, pivot LEFT) multiview stereo pair."""
    data = bpy.data.cameras.new(name)
    obj = bpy.data.objects.new(name, data)
    scene.collection.objects.link(obj)
    scene.camera = obj
    set_intrinsics(scene, obj, intrinsics)
    data.clip_start, data.clip_end = clip_start, clip_end
    data.stereo.convergence_mode = "PARALLEL"
    data.stereo.pivot = "LEFT"
    data.stereo.interocular_distance = baseline
    scene.render.use_multiview = True
    scene.render.views_format = "STEREO_3D"
    for view in scene.render.views:
        view.use = view.name in ("left", "right")
    return obj


def animate_camera(scene, camera, path: CameraPath) -> None:
    """The camera keyed on every frame 0..F-1 of its path (Blender axes); frame range and fps from the path."""
    poses = blender_pose_from_opencv(np.asarray(path.T_world_cam, dtype=np.float64).reshape(-1, 4, 4))
    scene.frame_start, scene.frame_end = 0, len(poses) - 1
    scene.render.fps = max(1, round(path.fps))
    scene.render.fps_base = scene.render.fps / path.fps
    key_poses(scene, camera, poses)


def key_poses(scene, obj, matrices: np.ndarray) -> None:
    """One linear key per frame 0..F-1 on location and rotation_quaternion from rigid ``matrix_world``s
    (F, 4, 4); quaternions are kept in one hemisphere so no key flips."""
    poses = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    count = len(poses)
    locs = poses[:, :3, 3]
    # float64 quaternions (mathutils works in float32: 5e-7 pose error instead of 1e-7), scalar first
    quats = np.roll(Rotation.from_matrix(poses[:, :3, :3]).as_quat(), 1, axis=1)
    for i in range(1, count):
        if np.dot(quats[i], quats[i - 1]) < 0:  # same hemisphere: no flip between keys
            quats[i] = -quats[i]
    obj.rotation_mode = "QUATERNION"
    obj.location, obj.rotation_quaternion = locs[0], quats[0]
    if count == 1:
        return
    obj.animation_data_create()
    action = bpy.data.actions.new(f"{obj.name}Path")
    obj.animation_data.action = action
    frames = np.arange(count, dtype=np.float64)
    for data_path, values in (("location", locs), ("rotation_quaternion", quats)):
        for index in range(values.shape[1]):
            fcurve = action.fcurve_ensure_for_datablock(obj, data_path, index=index)
            fcurve.keyframe_points.add(count)
            fcurve.keyframe_points.foreach_set("co", np.stack([frames, values[:, index]], 1).ravel())
            for key in fcurve.keyframe_points:
                key.interpolation = "LINEAR"
            fcurve.update()


def add_scope_light(camera, light: Light, name: str = LIGHT) -> list:
    """Spot or point light(s) parented to the camera at the light's outlets (OpenCV camera frame)."""
    if light.kind not in ("spot", "point"):
        raise ValueError(f"unknown light kind {light.kind!r}; choose 'spot' or 'point'")
    offsets = light.outlet_offsets()
    return [_add_outlet(camera, light, offset, light.power_w / len(offsets), name if i == 0 else f"{name}_{i + 1}")
            for i, offset in enumerate(offsets)]


def _add_outlet(camera, light: Light, offset, power_w: float, name: str):
    data = bpy.data.lights.new(name, type=light.kind.upper())
    data.energy = power_w
    data.shadow_soft_size = light.radius
    if light.kind == "spot":
        data.spot_size = math.radians(min(light.spot_size_deg, 180.0))
        data.spot_blend = SPOT_BLEND
    obj = bpy.data.objects.new(name, data)
    camera.users_collection[0].objects.link(obj)
    obj.parent = camera
    obj.matrix_parent_inverse = Matrix.Identity(4)
    x, y, z = offset
    obj.location = (x, -y, -z)  # OpenCV camera frame -> Blender camera frame
    obj.rotation_euler = (0.0, 0.0, 0.0)  # spot points down the camera's -Z: along the view
    return obj


def set_world(scene, ambient: float = 0.0) -> None:
    """Black world (the scope light only); ``ambient`` > 0 adds a uniform white light of that strength."""
    world = bpy.data.worlds.new("World")
    scene.world = world
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0) if ambient > 0 else (0.0, 0.0, 0.0, 1.0)
    background.inputs["Strength"].default_value = max(ambient, 0.0)


# --- output ----------------------------------------------------------------------------------------

def save_blend(path: str | Path) -> None:
    """Save the current file to ``path`` atomically (temporary name in the same folder, then rename)."""
    with atomic_path(path, suffix=".blend") as tmp:
        tmp.unlink()  # Blender would otherwise keep the empty placeholder as a .blend1 backup
        bpy.ops.wm.save_as_mainfile(filepath=str(tmp), copy=True, compress=True)
        Path(str(tmp) + "1").unlink(missing_ok=True)


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return str(obj)
