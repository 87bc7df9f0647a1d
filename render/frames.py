"""Render one bounded chunk of frames of a scene folder into a dataset folder (needs ``bpy``).

The worker (``python -m render.worker TASK.json``, see :mod:`rgbd2scene.stages.blender`) calls
:func:`render_task` for a ``render`` task: frames [start, end) of the dataset, with the render options and
the scene model of the task. K, the baseline and every pose written to the npz come from the model
(float64); the .blend must agree with it (checked when it opens). Outputs that exist are not rendered
again (resume). Progress goes out as the protocol's lines (``frame 3 rgb ...``, ``frame 3 done ...``,
``frame 3 skipped``).

Each frame's images come from one RGB render, both eyes (Blender multiview, PARALLEL, pivot LEFT): the scene
as built, ``--samples`` per pixel (adaptive, Cycles' blue-noise pattern), the usual pixel filter, motion blur
(shutter centred on the frame) and depth of field when asked for; Blender writes the linear Combined pass (and
the Depth pass when an environment effect needs ray lengths) as a 32-bit EXR, and numpy makes the PNGs:
environment effects, auto exposure and the sensor model
(:class:`rgbd2scene.dataset.develop_frames.FrameDeveloper`). Frame i renders while frame i-1 is developed and
written (:func:`_rgb_phase`).

Ground truth (``--gt-source model``, the default) does not come from Blender: every map is ray-cast from the
scene model along each pixel's own ray (:mod:`rgbd2scene.groundtruth.model_maps`), in a low-priority child
process started before the blend opens (:class:`rgbd2scene.groundtruth.background.BackgroundGroundTruth`), so
it fills the render's idle moments; the worker waits for the maps only after its last image.

``--gt-source blender`` (the independent cross-check, also ``verify --blender-frames``) renders each frame a
second time for its data: 1 sample per pixel, pixel filter width 0.01 (the one sample goes through the pixel
centre, +-0.005 px), ``max_bounces`` 0, no denoising, a black emission material override (the geometry alone
decides every pass; the blend's own sampling pattern, so the one sample stays at the pixel centre), passes
Depth, Normal, Vector and Object Index as a 32-bit multilayer EXR. A Mask modifier keeps, per part, the
triangles the two eyes can see and their one-ring
(:meth:`~rgbd2scene.groundtruth.scene_geometry.SceneGeometry.view_support`), so the passes are the whole
mesh's bit for bit (``tests/test_motion.py``) for a fraction of the sync and BVH time. The passes become the
maps in :func:`rgbd2scene.groundtruth.gt_from_passes`.

Maps are written by :mod:`rgbd2scene.dataset` (atomic). Temporary files live in the run's own scratch folder
``DATASET/.work/<run>/`` (locked while the run lives) and are removed. Cost: benchmarks/results/render.md,
issue16.md and profile.md.
"""

from __future__ import annotations

import contextlib
import math
import resource
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import blender_pose_from_opencv
from rgbd2scene.dataset import layout as ds
from rgbd2scene.dataset.develop_frames import FrameDeveloper
from rgbd2scene.groundtruth.background import BackgroundGroundTruth, Job
from rgbd2scene.groundtruth.passes import depth_from_pass, gt_from_passes, passes_needed
from rgbd2scene.groundtruth.scene_geometry import SceneGeometry, occlusion_maps
from rgbd2scene.rendering import (
    DENOISERS,
    ENGINES,
    GT_FILTER_WIDTH_PX,
    GT_MAX_BOUNCES,
    GT_SAMPLES,
    RGB_SAMPLING_PATTERN,
    Engine,
    RenderOptions,
)
from rgbd2scene.scene.folder import SCENE_BLEND
from rgbd2scene.scene.model import SceneDescription
from rgbd2scene.scene.raw import raw_render_plan
from rgbd2scene.worker_protocol import Render, frame_line, ready_line, resident_mb

GT_MATERIAL = "rgbd2scene_gt_override"
VIEWS = {"left": "_L", "right": "_R"}
#: Pass name in the EXR channel names (``<ViewLayer>.<pass>.<channel>``) -> our pass key.
EXR_PASSES = {"depth": ("Depth", "Z"), "normal": ("Normal", "XYZ"), "vector": ("Vector", "XYZW"),
              "index": ("Object Index", "X"), "combined": ("Combined", "RGB")}
#: How far (matrix entries, metres for translations) the blend's keyed camera may be from the model's pose:
#: Blender keys in float32 (measured 4e-7).
POSE_TOLERANCE = 1e-5
#: Vertex group and Mask modifier that cut a part down to what a data render needs (``Renderer.mask_views``).
VIEW_MASK = "rgbd2scene_in_view"
#: Name prefix of the hidden second user of a rigid mesh (:meth:`Renderer._share_rigid_meshes`).
BVH_INSTANCE = "rgbd2scene_bvh_instance"


class WorkerError(RuntimeError):
    pass


@dataclass
class ViewMask:
    """The Mask modifier and vertex group of one part's object (``part``: its index in the scene geometry)
    and the vertex indices the group holds."""

    part: int
    group: object
    modifier: object
    kept: list[int] = field(default_factory=list)


# --- Blender set-up --------------------------------------------------------------------------------------

def _set_engine(bpy, scene, engine: Engine) -> str:
    """Render with ``engine`` (on its first GPU back-end that finds a device); returns the device in words."""
    scene.render.engine = engine.blender
    if not engine.gpu:
        scene.cycles.device = "CPU"
        return "CPU"
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for kind in engine.backends:
        try:
            prefs.compute_device_type = kind
        except TypeError:
            continue
        prefs.get_devices()
        gpus = [d for d in prefs.devices if d.type == kind]
        if gpus:
            for d in prefs.devices:
                d.use = d.type == kind
            scene.cycles.device = "GPU"
            return f"GPU ({kind}: {', '.join(d.name for d in gpus)})"
    raise WorkerError(f"--engine {engine.name}: Cycles found no GPU ({', '.join(engine.backends)})")


def _gt_material(bpy):
    """Black emission: no light, BSDF or subsurface is evaluated; the Normal pass is the mesh's normal."""
    mat = bpy.data.materials.get(GT_MATERIAL)
    if mat is None:
        mat = bpy.data.materials.new(GT_MATERIAL)
        nodes = mat.node_tree.nodes
        nodes.clear()
        out = nodes.new("ShaderNodeOutputMaterial")
        emission = nodes.new("ShaderNodeEmission")
        emission.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        emission.inputs["Strength"].default_value = 0.0
        mat.node_tree.links.new(emission.outputs["Emission"], out.inputs["Surface"])
    return mat


class Renderer:
    """The open scene plus the two render configurations (RGB, data) it switches between."""

    def __init__(self, bpy, scene_dir: Path, out_dir: Path, description: SceneDescription,
                 options: RenderOptions, frames: int, scratch: Path, gt_process=None, gt_frames=()):
        self.bpy = bpy
        self.out_dir = out_dir
        self.description = description
        self.frames = int(frames)
        # ground truth from the scene model (groundtruth.model_maps), or from Blender's passes (the cross-check).
        # The model's maps come from a low-priority child process (groundtruth.background), started first: it
        # loads the model (open3d, the parts' geometry) while Blender opens the scene; ``gt_process``: that child
        # started already (groundtruth.background.spawn, by the worker before it imported bpy). It is asked for
        # ``gt_frames`` at once: it computes them while Blender opens the scene (one core) and renders
        self.from_model = options.gt_from_model
        self.model_gt = None
        if self.from_model:
            self.model_gt = BackgroundGroundTruth(Job(description.to_dict(), str(scene_dir), self.frames,
                                                      list(options.maps), str(out_dir), str(scratch)),
                                                  process=gt_process)
            self.model_gt.submit(gt_frames)
        blend = scene_dir / SCENE_BLEND
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        scene = self.scene = bpy.context.scene
        camera = scene.camera or bpy.data.objects.get("Endoscope")
        if camera is None or camera.type != "CAMERA":
            raise WorkerError(f"{blend}: the scene has no camera")
        self.camera = camera

        # intrinsics of the model (already resized by the render stage) -> resolution, lens, shift, aspect
        from render.scene_builder import set_intrinsics

        self.rig = description.rig
        # a raw pair (distortion, unequal eyes) is rendered as its rectified pair covering every raw pixel's
        # ray, then resampled into the raw grid (rgbd2scene.scene.raw); the camera then follows the model's
        # (rectified) poses instead of the blend's keys, as for a pair rectified from a raw rig (--rectify)
        self.raw = None if self.rig.rectified else raw_render_plan(self.rig)
        self.drive_camera = self.raw is not None or bool(options.rectify)
        if self.drive_camera:
            camera.animation_data_clear()
        set_intrinsics(scene, camera, self.raw.intrinsics if self.raw else self.rig.intrinsics)
        self.K = self.rig.intrinsics.K
        self.baseline = self.rig.baseline
        _check_blend_agrees(scene, camera, description, blend)
        for view in scene.render.views:
            view.use = view.name in VIEWS

        scene.render.use_motion_blur = False  # the Vector pass needs it off
        scene.render.use_file_extension = True
        # keep Cycles' scene between the RGB renders of a chunk: back-to-back renders then skip the mesh
        # sync, and with the meshes instanced (_share_rigid_meshes) their BVH build too. The data renders turn
        # it off (configure_data): with it, their normals depended on what the process rendered before
        # (one float32 step apart between a resumed and an uninterrupted run); fresh, they are identical.
        scene.render.use_persistent_data = bool(options.persistent_data)
        # no metadata that changes from run to run (date, render time, host, scratch file name) in the PNGs:
        # the same scene and settings give the same bytes
        for attr in dir(scene.render):
            if attr.startswith("use_stamp"):
                setattr(scene.render, attr, False)
        scene.render.image_settings.views_format = "INDIVIDUAL"
        self.device = _set_engine(bpy, scene, ENGINES[options.engine])
        if options.threads and options.threads > 0:
            scene.render.threads_mode = "FIXED"
            scene.render.threads = int(options.threads)
        self.samples, self.adaptive, self.seed = options.samples, options.adaptive, options.seed
        self.persistent_data = bool(options.persistent_data)
        self.denoiser = DENOISERS[options.denoise]
        self.prefilter = options.prefilter.upper()
        self.denoise_quality = options.denoise_quality.upper()
        self.rgb_filter_width = float(scene.cycles.filter_width)
        self.rgb_max_bounces = int(scene.cycles.max_bounces)
        # the data render keeps the blend's pattern: its one sample stays where it was (the same passes)
        self.data_sampling_pattern = scene.cycles.sampling_pattern
        self.maps = options.maps
        self.sensor = options.sensor
        # the linear render is in the rendered grid (the rectified pair of a raw rig): the environment's ray
        # lengths use its K; the raw pair's lens resampling comes before metering and the sensor
        rendered = self.raw.intrinsics if self.raw else self.rig.intrinsics
        self.developer = FrameDeveloper(out_dir, options.sensor, options.environment, options.seed,
                                        description.path.fps, rendered.K,
                                        lens=None if self.raw is None else self.raw.resample)
        self.passes = passes_needed(self.maps)
        self.gt_material = _gt_material(bpy) if self.maps and not self.from_model else None
        self.view_layer = scene.view_layers[0]
        for layer in scene.view_layers[1:]:
            layer.use = False
        self.images_at_start = {img.name for img in bpy.data.images}
        self.work = scratch
        # anything but the camera moves: occlusion maps and deformed vertices from the model's own geometry
        self.moving = any(part.moving for _, part in description.parts())
        # culling needs the parts' geometry files (a scene folder may hold only its .blend: rendered whole)
        cull = bool(options.view_culling) and all((Path(scene_dir) / p.geometry).is_file()
                                                  for _, p in description.parts())
        need_geometry = self.maps and (self.moving or cull) and not self.from_model
        self.geometry = SceneGeometry(description, scene_dir) if need_geometry else None
        self.view_masks = self._add_view_masks() if self.maps and cull and not self.from_model else []
        if self.persistent_data and not (self.maps and not self.from_model):
            self._share_rigid_meshes()

    def _share_rigid_meshes(self) -> None:
        """Give every rigid mesh (no shape keys, no modifiers) a second, hidden user, so that Cycles keeps its
        BVH between the frames of a chunk.

        Cycles' final renders use a static BVH: a mesh with one user gets its object's transform baked into
        its vertices and its triangles go into one flat BVH, which is rebuilt whole whenever any object moves,
        and the scope's lights move with the camera every frame (0.25 CPU s per stereo frame on a 300k-vertex
        mesh). A mesh with two users is instanced instead: its own BVH is built once and only the small top
        level is rebuilt. The second user sees only volume-scatter rays, which these scenes never trace (no
        volumes), so no ray can hit it. Intersections then happen in object space: the image is the same
        render up to float rounding in the hit points (1-spp noise differs pixel by pixel, the statistics do
        not: benchmarks/results/issue16.md section 3). Only where Blender renders no data passes (their
        bytes stay as they were)."""
        for obj in [o for o in self.scene.objects if o.type == "MESH"]:
            if obj.data.shape_keys is not None or obj.modifiers:
                continue  # its evaluated mesh is the object's own: a second object would not share it
            twin = obj.copy()
            twin.name = f"{BVH_INSTANCE}_{obj.name}"
            twin.animation_data_clear()
            twin.pass_index = 0  # not a part of the scene model (pose and id checks look up parts by id)
            for ray in ("camera", "diffuse", "glossy", "transmission", "shadow"):
                setattr(twin, f"visible_{ray}", False)
            twin.visible_volume_scatter = True  # one ray type left on, else Cycles drops it (no second user)
            self.scene.collection.objects.link(twin)

    def _add_view_masks(self) -> list[ViewMask]:
        """A Mask modifier (first in the stack, after the shape keys; off in RGB renders) and its vertex group
        on each part's object, so that data renders sync only what the frame's eyes need."""
        by_id = {o.pass_index: o for o in self.scene.objects if o.type == "MESH"}
        out = []
        for index, mesh in enumerate(self.geometry.meshes):
            obj = by_id.get(mesh.part.id)
            if obj is None or len(obj.data.vertices) != len(mesh.vertices):
                continue  # not built from the part's geometry file as it is: rendered whole
            group = obj.vertex_groups.new(name=VIEW_MASK)
            modifier = obj.modifiers.new(VIEW_MASK, "MASK")
            modifier.vertex_group = group.name
            modifier.show_render = modifier.show_viewport = False
            obj.modifiers.move(len(obj.modifiers) - 1, 0)
            out.append(ViewMask(index, group, modifier))
        return out

    def mask_views(self, index: int) -> None:
        """Keep, in the data render of frame ``index``, only the vertices its two eyes need
        (:meth:`SceneGeometry.view_support`: the passes are those of the whole scene, bit for bit)."""
        for mask in self.view_masks:
            keep = self.geometry.view_support(mask.part, index, (self.rig.left, self.rig.right)).tolist()
            if mask.kept:
                mask.group.remove(mask.kept)
            mask.group.add(keep, 1.0, "REPLACE")
            mask.kept = keep

    # -- configurations --
    # Only changed values are assigned: any assignment tags Blender data as updated, and with persistent
    # data an updated material (override) makes Cycles rebuild the geometry and its BVH.

    def configure_rgb(self) -> None:
        sc, cy, vl = self.scene, self.scene.cycles, self.view_layer
        _apply([(sc.render, "use_persistent_data", self.persistent_data),
                (cy, "samples", self.samples), (cy, "use_adaptive_sampling", self.adaptive),
                (cy, "filter_width", self.rgb_filter_width), (cy, "max_bounces", self.rgb_max_bounces),
                (cy, "use_denoising", self.denoiser.blender is not None), (cy, "seed", self.seed),
                (cy, "use_animated_seed", True),  # a different (reproducible) noise pattern per frame
                (cy, "sampling_pattern", RGB_SAMPLING_PATTERN),
                (vl, "material_override", None), (vl, "use_pass_combined", True),
                # Depth only for environment effects (ray lengths through smoke)
                (vl, "use_pass_z", self.developer.needs_depth), (vl, "use_pass_normal", False),
                (vl, "use_pass_vector", False), (vl, "use_pass_object_index", False)])
        if self.denoiser.blender:
            _apply([(cy, "denoiser", self.denoiser.blender)])
        if self.denoiser.prefilter:
            _apply([(cy, "denoising_prefilter", self.prefilter), (cy, "denoising_quality", self.denoise_quality)])
        _apply([(mask.modifier, "show_render", False) for mask in self.view_masks])
        blur, focus = self.sensor.motion_blur, self.sensor.focus_distance
        _apply([(sc.render, "use_motion_blur", blur > 0), (self.camera.data.dof, "use_dof", focus > 0)])
        if blur > 0:  # the ground truth is at the frame: the middle of the shutter
            _apply([(sc.render, "motion_blur_position", "CENTER"), (sc.render, "motion_blur_shutter", blur)])
        if focus > 0:  # Cycles' aperture diameter is lens / f-number (both in mm of its virtual 36 mm sensor)
            _apply([(self.camera.data.dof, "focus_distance", focus),
                    (self.camera.data.dof, "aperture_fstop", self.camera.data.lens / self.sensor.aperture_mm)])
        # the linear render for the sensor model: Combined (+ Depth), 32-bit EXR
        s = sc.render.image_settings
        _apply([(s, "media_type", "MULTI_LAYER_IMAGE"), (s, "file_format", "OPEN_EXR_MULTILAYER"),
                (s, "color_depth", "32"), (s, "exr_codec", "NONE"), (s, "use_exr_interleave", True),
                (s, "views_format", "INDIVIDUAL")])

    def configure_data(self) -> None:
        sc, cy, vl, p = self.scene, self.scene.cycles, self.view_layer, self.passes
        _apply([(sc.render, "use_persistent_data", False),  # history-independent ground truth (see __init__)
                (cy, "samples", GT_SAMPLES), (cy, "use_adaptive_sampling", False),
                (cy, "filter_width", GT_FILTER_WIDTH_PX),
                (cy, "max_bounces", GT_MAX_BOUNCES), (cy, "use_denoising", False), (cy, "seed", 0),
                (cy, "use_animated_seed", False), (cy, "sampling_pattern", self.data_sampling_pattern),
                (vl, "material_override", self.gt_material),
                (vl, "use_pass_z", True), (vl, "use_pass_normal", "normal" in p),
                (vl, "use_pass_vector", "vector" in p), (vl, "use_pass_object_index", "index" in p)]
               + [(mask.modifier, "show_render", True) for mask in self.view_masks]
               # exact per pixel centre at the frame: no shutter interval, no aperture
               + [(sc.render, "use_motion_blur", False), (self.camera.data.dof, "use_dof", False)])
        s = sc.render.image_settings
        _apply([(s, "media_type", "MULTI_LAYER_IMAGE"), (s, "file_format", "OPEN_EXR_MULTILAYER"),
                (s, "color_depth", "32"),  # half floats round depth by up to 0.03 mm
                (s, "exr_codec", "NONE"),  # scratch file, read back at once: fastest
                (s, "use_exr_interleave", True),  # one part (multi-part fails in 5.0.1 when fx != fy)
                (s, "views_format", "INDIVIDUAL")])

    def _render(self, base: Path, ext: str) -> dict[str, Path]:
        self.scene.render.filepath = str(base)
        self.bpy.ops.render.render(write_still=True)
        files = {eye: Path(f"{base}{suffix}{ext}") for eye, suffix in VIEWS.items()}
        missing = [str(p) for p in files.values() if not p.is_file()]
        if missing:
            raise WorkerError(f"Blender did not write {', '.join(missing)}")
        return files

    # -- one frame --

    def set_frame(self, index: int) -> None:
        """Go to frame ``index``: the blend's animation, and the camera at the model's pose when it follows the
        model (:attr:`drive_camera`); then check every pose against the model."""
        self.scene.frame_set(index)
        if self.drive_camera:
            from mathutils import Matrix

            T = self.description.camera_pose(index)
            if self.raw is not None:
                T = self.raw.rectified_pose(T)
            self.camera.matrix_world = Matrix(blender_pose_from_opencv(T).tolist())
        _check_pose(self.scene, self.camera, self.description, index, camera_keyed=not self.drive_camera)

    def render_linear(self, index: int) -> tuple[dict, dict | None]:
        """The current frame's linear RGB render of both eyes, float32 (H, W, 3), and its Depth pass (only when
        the environment needs it)."""
        self.configure_rgb()
        files = self._render(self.work / f"{ds.frame_name(index)}_rgb", ".exr")
        linear, depth = {}, {} if self.developer.needs_depth else None
        try:
            for eye, path in files.items():
                passes = read_passes(path, {"combined", "depth"} if depth is not None else {"combined"})
                linear[eye] = passes["combined"]
                if depth is not None:
                    depth[eye] = passes["depth"]
        finally:
            for path in files.values():
                path.unlink(missing_ok=True)
        return linear, depth

    def meter_frame(self, index: int) -> None:
        """Render frame ``index`` only to meter it for the auto exposure of the frames after it."""
        self.set_frame(index)
        linear, depth = self.render_linear(index)
        left = self.developer.scene_linear(index, "left", linear["left"], None if depth is None else depth["left"])
        self.developer.meter(index, left)

    def render_data(self, index: int) -> dict:
        """The data render of the current frame (Blender side): EXR files; poses and tracked objects from
        the model."""
        self.configure_data()
        self.mask_views(index)
        files = self._render(self.work / f"{ds.frame_name(index)}_data", ".exr")
        poses = {eye: self.description.camera_pose(index, eye) for eye in VIEWS}
        ids, obj_poses = self.description.tracked_poses(index)
        return {"index": index, "files": files, "poses": poses, "object_ids": ids, "object_poses": obj_poses}

    def model_maps(self, index: int) -> dict:
        """What the scene model alone gives of frame ``index`` when anything but the camera moves: per eye
        its occlusion maps, and ``"geometry"``, the deformed parts' vertices. No ``bpy`` and no passes: runs
        in a thread while Blender renders. Empty for a static scene."""
        if not self.moving:
            return {}
        out: dict = {eye: occlusion_maps(self.geometry, index, self.frames, eye, self.rig.camera(eye))
                     for eye in VIEWS}
        out["geometry"] = {f"vertices_{pid}": self.geometry.part_vertices(i, index).astype(np.float32)
                           for pid, i in self.geometry.deformed()}
        return out

    def write_gt(self, job: dict, model: Future) -> None:
        """Passes -> ground truth -> npz of both eyes, with ``model`` (:meth:`model_maps` of the frame) added;
        removes the EXRs. No ``bpy``: runs in a thread."""
        index = job["index"]
        try:
            from_model = model.result()
            for eye, path in job["files"].items():
                passes = read_passes(path, self.passes | {"depth"})
                gt = gt_from_passes(passes["depth"], passes.get("normal"), passes.get("vector"),
                                    passes.get("index"), self.K, job["poses"][eye], self.baseline,
                                    first=index == 0, last=index == self.frames - 1,
                                    object_ids=job["object_ids"], object_poses=job["object_poses"],
                                    maps=self.maps, D=self.rig.camera(eye).distortion)
                surface = np.isfinite(gt.get("depth", depth_from_pass(passes["depth"])))
                for key, flags in from_model.get(eye, {}).items():
                    gt[key] = flags & surface
                ds.write_gt(ds.frame_paths(self.out_dir, eye, index).gt, gt, scratch=self.work)
            if from_model.get("geometry"):
                ds.write_gt(ds.geometry_path(self.out_dir, index), from_model["geometry"], scratch=self.work)
        finally:
            for path in job["files"].values():
                path.unlink(missing_ok=True)

    def free_images(self) -> None:
        """Remove image datablocks that appeared while rendering (memory)."""
        images = self.bpy.data.images
        for img in list(images):
            if img.name not in self.images_at_start and img.type not in ("RENDER_RESULT", "COMPOSITING"):
                images.remove(img)


def _apply(settings) -> None:
    """Assign (owner, attribute, value) triples whose value differs (floats: to float32 precision)."""
    for owner, attr, value in settings:
        old = getattr(owner, attr)
        if isinstance(value, float) and isinstance(old, float):
            if math.isclose(old, value, rel_tol=1e-6):
                continue
        elif old == value:
            continue
        setattr(owner, attr, value)


def read_passes(path: Path, wanted) -> dict[str, np.ndarray]:
    """Passes of one eye from Blender's multilayer EXR: depth (H,W), normal (H,W,3), vector (H,W,4),
    index (H,W); rows top first. Channels are found by name (``<layer>.<pass>.<channel>``)."""
    import OpenEXR

    exr = OpenEXR.File(str(path), separate_channels=True)
    channels: dict[str, np.ndarray] = {}
    for part in exr.parts:
        channels.update({name: ch.pixels for name, ch in part.channels.items()})
    out = {}
    for key in wanted:
        pass_name, letters = EXR_PASSES[key]
        arrays = []
        for letter in letters:
            suffix = f".{pass_name}.{letter}"
            hits = [n for n in channels if n.endswith(suffix) or n == suffix[1:]]
            if not hits:
                raise WorkerError(f"{path}: no channel *{suffix} (channels: {', '.join(sorted(channels))})")
            arrays.append(np.asarray(channels[sorted(hits)[0]], dtype=np.float32))
        out[key] = arrays[0] if len(arrays) == 1 else np.stack(arrays, axis=-1)
    return out


# --- the render task -----------------------------------------------------------------------------------

def _check_blend_agrees(scene, camera, description: SceneDescription, blend: Path) -> None:
    """The .blend must be the model's scene: rectified stereo (PARALLEL, pivot LEFT) at the model's baseline,
    and an object with each part's instance id."""
    stereo = camera.data.stereo
    if not scene.render.use_multiview or scene.render.views_format != "STEREO_3D":
        raise WorkerError(f"{blend}: the scene is not a stereo (multiview STEREO_3D) scene")
    if stereo.convergence_mode != "PARALLEL" or stereo.pivot != "LEFT":
        raise WorkerError(f"{blend}: stereo must be PARALLEL with pivot LEFT, found "
                          f"{stereo.convergence_mode} / {stereo.pivot}")
    if not math.isclose(stereo.interocular_distance, description.rig.baseline, rel_tol=1e-6):
        raise WorkerError(f"{blend}: baseline {stereo.interocular_distance} differs from the scene model's "
                          f"{description.rig.baseline}")
    ids = {o.pass_index for o in scene.objects if o.type == "MESH"}
    missing = [p.id for _, p in description.parts() if p.id not in ids]
    if missing:
        raise WorkerError(f"{blend}: no object with instance id(s) {missing} of the scene model")


def _check_pose(scene, camera, description: SceneDescription, index: int, camera_keyed: bool = True) -> None:
    """The camera (when ``camera_keyed``) and every posed part Blender renders (keyed on their tracks) are at
    the model's poses of this frame."""
    checks = [("camera", camera, blender_pose_from_opencv(description.camera_pose(index)))] if camera_keyed else []
    by_id = {o.pass_index: o for o in scene.objects if o.type == "MESH"}
    checks += [(f"part {p.id}", by_id[p.id], p.pose_at(index)) for _, p in description.parts() if p.poses is not None]
    for what, obj, expected in checks:
        found = np.array(obj.matrix_world, dtype=np.float64)
        if not np.allclose(found, expected, atol=POSE_TOLERANCE):
            raise WorkerError(f"frame {index}: the blend's {what} pose differs from the scene model's by "
                              f"{np.abs(found - expected).max():.2e} (> {POSE_TOLERANCE})")


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _rgb_phase(renderer: Renderer, need_rgb: list[int], need_gt: list[int], say) -> dict[int, tuple[float, float]]:
    """Every RGB frame of the chunk, pipelined: one thread develops frame i-1 (environment, auto exposure,
    sensor, PNGs; in frame order, so each frame's metering is there for the next) while Blender renders frame i.
    With ground truth from the scene model (no data render) the child process ``renderer.model_gt``
    (:class:`~rgbd2scene.groundtruth.background.BackgroundGroundTruth`) was asked for every frame's maps before
    the blend opened and writes them meanwhile, in the CPU time the render leaves idle; a frame is done (in frame order)
    when its images and its maps are, and the render waits for the maps only after its last image. Returns
    the (wall, CPU) seconds of the frames a data render still has to finish (Blender's passes)."""
    model = renderer.model_gt  # asked for every frame of need_gt when it was started (Renderer)
    spent: dict[int, tuple[float, float]] = {}
    maps_here = set(need_gt) if model is not None else set()  # frames the child writes the maps of
    t_mark, c_mark = time.perf_counter(), _cpu_s()
    t_images = t_mark  # when the latest frame's images were done
    waiting: list[tuple[int, float]] = []  # (frame, the seconds its images took), in frame order

    def finish(block: bool) -> None:
        """Send the done line of the frames at the front of ``waiting`` whose maps are written (of all of
        them, waiting for the maps, when ``block``)."""
        nonlocal t_mark, c_mark
        blocked = time.perf_counter()  # the render waits for the maps only from here, and only when ``block``
        while waiting and (block or waiting[0][0] not in maps_here or model.done(waiting[0][0])):
            index, t_rgb = waiting.pop(0)
            child = model.wait(index) if index in maps_here else None
            now, cpu = time.perf_counter(), _cpu_s()
            t_frame, c_frame = now - t_mark, cpu - c_mark + (child.cpu_s if child else 0.0)  # this frame's share
            t_gt = now - max(blocked, t_mark) if block else 0.0  # the wait for the maps: what they added
            t_mark, c_mark = now, cpu
            say(frame_line(index, "done", t_frame, cpu=c_frame, rgb=t_rgb, gt=t_gt, rss=resident_mb(),
                           **({"gt_rss": child.rss_mb} if child else {})))

    with ThreadPoolExecutor(max_workers=1) as develop_pool:
        developing: list[tuple[int, Future]] = []
        for index in need_rgb + [None]:
            if index is not None:
                # metering a chunk starts without (frames of this chunk are metered in turn by the thread)
                for earlier in renderer.developer.missing_history(index, coming=need_rgb):
                    renderer.meter_frame(earlier)
                renderer.set_frame(index)
                linear, depth = renderer.render_linear(index)
                renderer.free_images()
                developing.append((index, develop_pool.submit(renderer.developer.develop_frame, index, linear,
                                                              depth)))
            while developing and (index is None or len(developing) > 1):
                done_index, future = developing.pop(0)
                future.result()
                if done_index in need_gt and model is None:  # the frame is finished by the data render
                    now, cpu = time.perf_counter(), _cpu_s()
                    spent[done_index] = now - t_mark, cpu - c_mark
                    t_mark, c_mark = now, cpu
                    say(frame_line(done_index, "rgb", spent[done_index][0], cpu=spent[done_index][1],
                                   rss=resident_mb()))
                else:
                    now = time.perf_counter()
                    waiting.append((done_index, now - max(t_images, t_mark)))
                    t_images = now
                    finish(block=False)
    waiting += [(i, 0.0) for i in need_gt if i in maps_here and i not in set(need_rgb)]  # images there already
    finish(block=True)
    return spent


def render_task(bpy, task: Render, say, gt_process=None) -> None:
    """Render frames [task.start, task.end) of the task's dataset; ``say`` sends a protocol line; ``gt_process``: the
    model's ground-truth child when the worker started it already (:func:`rgbd2scene.groundtruth.background.spawn`)."""
    t0 = time.perf_counter()
    scene_dir, out_dir = Path(task.scene_dir), Path(task.dataset_dir)
    if not (scene_dir / SCENE_BLEND).is_file():
        raise WorkerError(f"{scene_dir}: no scene.blend")
    description = SceneDescription.from_dict(task.description)
    options = RenderOptions(**task.render).validated()
    frames = int(task.frames or description.frames)
    with ds.scratch_dir(out_dir) as scratch, contextlib.ExitStack() as stack:
        indices = range(max(task.start, 0), min(task.end or frames, frames))
        need_rgb = [i for i in indices if not ds.rgb_done(out_dir, i)]
        need_gt = [i for i in indices if options.maps and not ds.gt_done(out_dir, i, description.deforming)]
        renderer = Renderer(bpy, scene_dir, out_dir, description, options, frames, scratch, gt_process, need_gt)
        if renderer.model_gt is not None:  # the model's child process ends with the task
            stack.enter_context(renderer.model_gt)
        say(ready_line(time.perf_counter() - t0, renderer.device))
        for i in sorted(set(indices) - set(need_rgb) - set(need_gt)):
            say(frame_line(i, "skipped"))
        spent = _rgb_phase(renderer, need_rgb, need_gt, say)
        if renderer.from_model:
            return
        # Blender's passes (--gt-source blender, the cross-check of the model's maps): every data render after
        # every RGB render of the chunk. Switching between the two configurations makes Cycles rebuild its
        # scene (the material override changes the shaders), so alternating them per frame costs ~0.1 s more
        # per frame than running each kind back to back.
        # The data phase is pipelined: while Blender renders frame i's passes, one thread computes what the
        # model alone gives of frame i (occlusion maps, deformed vertices) and another converts and compresses
        # frame i-1's passes (the data render leaves a core idle: scene sync, BVH builds, 1 sample).
        t_mark, c_mark = time.perf_counter(), _cpu_s()
        with ThreadPoolExecutor(max_workers=1) as pool, ThreadPoolExecutor(max_workers=1) as model_pool:
            pending: list[tuple[int, Future]] = []
            for index in need_gt + [None]:
                if index is not None:
                    model = model_pool.submit(renderer.model_maps, index)
                    renderer.set_frame(index)
                    job = renderer.render_data(index)
                    renderer.free_images()
                    pending.append((index, pool.submit(renderer.write_gt, job, model)))
                while pending and (index is None or len(pending) > 1):
                    done_index, future = pending.pop(0)
                    future.result()
                    now, cpu = time.perf_counter(), _cpu_s()
                    t_gt, c_gt = now - t_mark, cpu - c_mark  # this frame's share of the phase
                    t_mark, c_mark = now, cpu
                    t_rgb, c_rgb = spent.get(done_index, (0.0, 0.0))
                    say(frame_line(done_index, "done", t_rgb + t_gt, cpu=c_rgb + c_gt, rgb=t_rgb, gt=t_gt,
                                   rss=resident_mb()))
