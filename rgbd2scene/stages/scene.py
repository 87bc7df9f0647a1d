"""The scene stage: a reconstruction (or a mesh folder) + rig + path + light -> SCENE folder with scene.blend.

The Blender work itself is in ``render.blender_scene``; this module decides what to build and records it
in ``scene.json`` (written last: a scene folder with a scene.json is complete).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd2scene.capture.camera import load_camera
from rgbd2scene.errors import UserError
from rgbd2scene.files.atomic import link_or_copy, read_json_object, write_json
from rgbd2scene.files.images import read_image, write_image
from rgbd2scene.files.meshio import read_ply
from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.raycast import raycaster
from rgbd2scene.geometry.stereo import StereoCalibration
from rgbd2scene.options import OptionError, flag_of, option, to_record
from rgbd2scene.scene import folder
from rgbd2scene.scene.config import ConfigError, SceneConfig, load_scene_config, parse_scene_config
from rgbd2scene.scene.deformation import KINDS as DEFORMATIONS
from rgbd2scene.scene.delight import DELIGHT_MODES, DELIGHT_SMOOTH_PX, MAX_GAIN, delight_texture
from rgbd2scene.scene.materials import TissueDetail
from rgbd2scene.scene.model import MATERIALS, Light, SceneDescription, tissue_object
from rgbd2scene.scene.objects.assemble import Tissue, add_objects
from rgbd2scene.scene.paths import (
    DEFAULT_STANDOFF,
    PATH_GENERATORS,
    CameraPath,
    load_path_file,
    make_path,
    path_coverage,
)
from rgbd2scene.scene.rig import DEFAULT_BASELINE, DEFAULT_FOV_X_DEG, DEFAULT_SIZE, StereoRig, read_scope_calibration
from rgbd2scene.stages.blender import BuildScene, Task, run_task
from rgbd2scene.stages.render import parse_size

#: Scope light power, watts (both outlets): auto exposure then needs no sensor gain at 8 cm from the bundled
#: sample's tissue (light at 0.40), dims the light nearer (0.08 at the default 4 cm standoff, 0.02 at 2 cm;
#: measured: benchmarks/bench_sensor.py, without vignetting since session 8; with the old vignetting it was
#: full power at 8 cm). The Hamlyn twin runs at light 0.98, gain 1 (benchmarks/results/twin.md): its noise is
#: then the real frame's noise law at gain 1. The 0.05 W before left a twin at 8 cm at 0.30 of the real frame's
#: brightness.
DEFAULT_LIGHT_W = 0.35
#: The working distance DEFAULT_LIGHT_W was chosen for (metres): beyond it the light grows with the square of
#: the distance (``SceneOptions.light_for_distance``), as a light source is chosen for its working distance.
LIGHT_REFERENCE_DISTANCE_M = 0.08
#: How far outside each lens a fibre outlet ends (two-outlet light), metres.
OUTLET_MARGIN_M = 0.0015

#: ``--path capture``: the digital twin's path, the scope still at the capture's own camera.
CAPTURE_PATH = "capture"


@dataclass
class SceneOptions:
    """Everything the user chooses about the scene (defaults: a da Vinci-class scope scanning tissue)."""

    size: tuple[int, int] = option(DEFAULT_SIZE, "endoscope image size WxH", parse=parse_size, metavar="WxH")
    fov_x_deg: float = option(DEFAULT_FOV_X_DEG, "horizontal field of view, degrees", flag="--fov")
    scope_camera: str | None = option(None, "endoscope intrinsics as a camera JSON (fx, fy, cx, cy, width, "
                                      "height, optionally distortion: OpenCV's D; both eyes share it, --baseline "
                                      "apart); overrides --size and --fov", file=True)
    scope_calib: str | None = option(None, "two calibrated scope eyes: an OpenCV FileStorage YAML (K1 D1 K2 D2 R "
                                     "T, image_width, image_height), a calibration JSON or a Hamlyn folder "
                                     "(image size from --size); overrides --scope-camera, --size, --fov and "
                                     "--baseline", file=True, metavar="FILE")
    baseline: float = option(DEFAULT_BASELINE, "stereo baseline, metres")
    path: str = option("scan", "generated camera path, or capture: the digital twin, the scope held still at the "
                       "capture's own camera (its K and image size; for stereo input the calibrated pair itself)",
                       choices=(*PATH_GENERATORS, CAPTURE_PATH))
    path_file: str | None = option(None, "JSON path file of waypoints (overrides --path)", file=True)
    frames: int = option(60, "frames in the path")
    fps: float = option(30.0, "frames per second")
    standoff: float = option(DEFAULT_STANDOFF, "distance to the tissue, metres")
    seed: int = option(0, "seed of generated paths")
    material: str = option("wet_tissue", "tissue look", choices=MATERIALS)
    tissue_detail: str = option("on", "procedural sub-millimetre micro-structure of the wet_tissue material (albedo "
                                "mottling, small vessels, bumps; seeded by --seed; shading only, the ground truth "
                                "does not change): on (baked into textures when the scene is built), procedural "
                                "(evaluated per sample: slower) or off", choices=("on", "procedural", "off"))
    light: str = option("spot", "light at the tip", choices=("spot", "point"))
    light_power_w: float = option(DEFAULT_LIGHT_W, "light power, watts (all outlets together)", flag="--light-power")
    light_for_distance: bool = option(True, "keep the light's power for a working distance beyond 8 cm: raise it "
                                      "with the square of the distance to the surface the path looks at (the twin "
                                      "of a capture taken from afar then needs no extreme gain)")
    light_outlets: int = option(2, "fibre outlets at the tip: 1 (between the eyes) or 2 (beside the lenses, "
                                "like a stereo scope's light guides)", choices=(1, 2))
    deform: str = option("none", "tissue motion: breathing, heartbeat (periodic displacement along the surface "
                         "normal) or none", choices=DEFORMATIONS)
    instrument: bool = option(False, "add the built-in instrument (shaft, wrist, two jaws) with its default motion "
                              "(unless the scene configuration has one)")
    delight: str = option("auto", "divide the capture light's shading out of the texture (inverse-square "
                          "fall-off, incidence angle, spot cone of the scope light at the capture camera), so the "
                          "render's light does not shade it twice: auto (for stereo endoscope captures, lit by the "
                          "scope's own light; not for RGB-D captures under room light, nor for the unlit "
                          "as_captured material), on or off; the texture as it was is kept as texture_lit.png",
                          choices=DELIGHT_MODES)
    delight_smooth: float = option(DELIGHT_SMOOTH_PX, "Gaussian sigma (texels) of the shading --delight divides "
                                   "out: the depth's pixel-scale normal noise stays out of the texture; 0 divides "
                                   "each texel by its own vertex's shading (exact only at the capture pose)",
                                   metavar="PX")
    scene_config: str | None = option(None, "scene configuration file (TOML or YAML): instruments, meshes, their "
                                      "motions, tracked frames, deformation", metavar="FILE")

    def rig(self) -> StereoRig:
        """The stereo rig; :class:`OptionError` naming the field when a value is implausible."""
        if self.baseline <= 0 or self.baseline > 0.1:
            raise OptionError("baseline", f"{self.baseline} m is not a plausible endoscope baseline (0-0.1 m)")
        if self.scope_calib is not None:
            return read_scope_calibration(self.scope_calib, self.size)
        if self.scope_camera is not None:
            return StereoRig.parallel(load_camera(self.scope_camera), self.baseline)
        intr = Intrinsics.from_fov(*self.size, self.fov_x_deg)
        intr.check("--fov/--size")
        return StereoRig.parallel(intr, self.baseline)


def scene_config(options: SceneOptions) -> SceneConfig | None:
    """The validated scene configuration of ``--scene-config`` (with ``--instrument``'s instrument), or of
    ``--instrument`` alone; None without either. :class:`UserError` naming the file and the key.

    A scope given by file (``--scope-camera``, ``--scope-calib``) is checked here too, so that a bad lens or
    calibration fails before anything is reconstructed or written."""
    if options.scope_calib or options.scope_camera:
        try:
            options.rig()
        except OptionError as exc:
            raise UserError(f"{flag_of(SceneOptions, exc.name)}: {exc.message}") from None
    if options.scene_config:
        try:
            return load_scene_config(options.scene_config, default_instrument=options.instrument)
        except ConfigError as exc:
            raise UserError(f"{options.scene_config}: {exc}") from None
    if options.instrument:
        return parse_scene_config({}, Path("."), default_instrument=True)
    return None


def _config_error(config: SceneConfig, exc: ConfigError) -> UserError:
    return UserError(f"{config.path}: {exc}" if config.path is not None else str(exc))


def capture_camera(record: dict, options: SceneOptions) -> tuple[StereoRig, np.ndarray]:
    """The rig and the (left eye's) pose of ``--path capture``: the capture's own camera (CONVENTIONS 1.2).

    For an RGB-D capture, its K and image size (``--baseline`` apart), at the identity (the world frame is the
    capture's camera frame, the first frame's for fused captures); for a stereo
    capture, the calibrated pair itself (K, D of each eye, R, T, the image size) at the identity, the
    calibration's left camera frame being the world frame.
    """
    capture = record.get("capture") or {}
    stereo = capture.get("stereo")
    try:
        if stereo is not None:
            calibration = StereoCalibration.from_dict(stereo["calibration_values"], source="the capture record")
            return StereoRig(calibration), np.eye(4)
        intrinsics = Intrinsics.from_dict(capture["intrinsics"])
    except (KeyError, TypeError) as exc:
        missing = f"no {exc}" if isinstance(exc, KeyError) else exc
        raise UserError(f"--path capture: the scene's capture record has no camera ({missing}); give a capture "
                        "(--rgb/--depth or --left/--right/--stereo-calib) or a mesh folder made from one") from None
    except ValueError as exc:
        what = "stereo calibration" if stereo is not None else "intrinsics"
        raise UserError(f"--path capture: the {what} in the scene's capture record: {exc}") from None
    if options.baseline <= 0 or options.baseline > 0.1:
        raise UserError(f"--baseline: {options.baseline} m is not a plausible endoscope baseline (0-0.1 m)")
    return StereoRig.parallel(Camera(intrinsics), options.baseline), np.eye(4)


def make_description(vertices: np.ndarray, triangles: np.ndarray, options: SceneOptions, rc=None,
                     texture: str | None = folder.TEXTURE, config: SceneConfig | None = None,
                     capture: tuple[StereoRig, np.ndarray] | None = None) -> SceneDescription:
    """The scene model: rig, path (generated over the mesh or read from a path file), light, and the tissue
    (``mesh.ply`` with ``texture``, or its vertex colours when None) with its deformation (``--deform``'s
    preset, or the configuration's, with the configuration's overrides).

    ``rc`` is a ready ``raycast.Raycaster`` of the mesh (built here if not given). The configuration's objects
    are added by :func:`build_scene_folder` (they write files). ``capture`` is the rig and pose of ``--path
    capture`` (:func:`capture_camera`): the scope holds still there for ``--frames`` frames.
    """
    if options.material not in MATERIALS:
        raise UserError(f"--material: unknown material {options.material!r}; choose one of {', '.join(MATERIALS)}")
    if options.light not in ("spot", "point"):
        raise UserError(f"--light: must be spot or point, got {options.light!r}")
    try:
        rig = options.rig() if capture is None else capture[0]
    except OptionError as exc:
        raise UserError(f"{flag_of(SceneOptions, exc.name)}: {exc.message}") from None
    if capture is not None and not options.path_file:
        path = CameraPath(np.repeat(capture[1][None], max(1, int(options.frames)), axis=0), float(options.fps),
                          kind=CAPTURE_PATH)
    elif options.path_file:
        try:
            path: CameraPath = load_path_file(options.path_file)
        except ValueError as exc:  # the message names the file
            raise UserError(str(exc)) from None
    else:
        try:
            path = make_path(options.path, vertices, triangles, rig, frames=options.frames, fps=options.fps,
                             seed=options.seed, standoff=options.standoff, rc=rc)
        except ValueError as exc:
            raise UserError(f"path: {exc}") from None
    power = float(options.light_power_w)
    if options.light_for_distance:
        distance = _working_distance(rc if rc is not None else raycaster(vertices, triangles), path)
        power *= max(1.0, distance / LIGHT_REFERENCE_DISTANCE_M) ** 2
    light = scope_light(options, rig, power)
    # only the wet-tissue material has the micro-structure: record what is built
    detail = TissueDetail(enabled=options.tissue_detail != "off" and options.material == "wet_tissue",
                          seed=options.seed, bake=options.tissue_detail != "procedural")
    tissue = tissue_object(options.material, folder.MESH, texture, detail)
    config = config or SceneConfig()
    if (config.deformation_preset or options.deform) != "none":
        # centred on the surface the camera looks at in the middle of the path
        centre = _view_target(rc if rc is not None else raycaster(vertices, triangles), path)
        try:
            tissue.parts[0].deformation = config.deformation(options.deform, centre=tuple(centre))
        except ConfigError as exc:
            raise _config_error(config, exc) from None
    return SceneDescription(rig, path, light, [tissue], environment=dict(config.environment))


def scope_light(options: SceneOptions, rig: StereoRig, power_w: float) -> Light:
    """The light at the tip of ``rig``: centred between the eyes; two outlets sit OUTLET_MARGIN_M outside the
    lenses."""
    return Light(kind=options.light, power_w=power_w, offset=(rig.baseline / 2, 0.0, 0.0),
                 outlets=options.light_outlets, outlet_spacing=rig.baseline + 2 * OUTLET_MARGIN_M)


def delight_choice(record: dict, options: SceneOptions, textured: bool) -> tuple[bool, str]:
    """Whether ``--delight`` divides the capture light out of the texture, and why (for scene.json)."""
    if options.delight == "off":
        return False, "--delight off"
    if not textured:
        return False, "no texture (the mesh has vertex colours only: fused frames, or no UVs)"
    if options.delight == "on":
        return True, "--delight on"
    if options.material == "as_captured":
        return False, "auto: the as_captured material is unlit, so the capture's shading counts once"
    if (record.get("capture") or {}).get("stereo") is not None:
        return True, ("auto: a stereo endoscope capture, lit by the scope's own light at the camera, whose shading "
                      "the render's light would apply a second time")
    return False, "auto: an RGB-D capture, lit by the room, not by a light at the camera"


def delight_scene_texture(out_dir: Path, mesh, record: dict, options: SceneOptions, textured: bool) -> dict:
    """Write the de-lit texture (``--delight``) as the scene's texture, the texture before as TEXTURE_LIT;
    without de-lighting, make sure the texture is the lit one. Returns scene.json's ``delight`` section."""
    applied, reason = delight_choice(record, options, textured)
    section = {"mode": options.delight, "applied": applied, "reason": reason}
    if not applied:
        if (out_dir / folder.TEXTURE_LIT).is_file():  # a scene folder rebuilt in place: back to the lit texture
            write_image(out_dir / folder.TEXTURE, mesh.texture)
            (out_dir / folder.TEXTURE_LIT).unlink()
        return section
    rig, T_world_cam = capture_camera(record, options)
    light = scope_light(options, rig, 1.0)
    if options.delight_smooth < 0:
        raise UserError(f"--delight-smooth: {options.delight_smooth} texels is negative")
    albedo, stats = delight_texture(mesh.texture, mesh.vertices, mesh.triangles, mesh.uvs, light, T_world_cam,
                                    smooth_px=options.delight_smooth)
    write_image(out_dir / folder.TEXTURE_LIT, mesh.texture)
    write_image(out_dir / folder.TEXTURE, albedo)  # atomic: a texture hard-linked from a mesh folder stays
    section.update({
        "method": "albedo = texture / (shading of the scope light at the capture camera), in linear light, per "
                  "texel: shading = sum over outlets of spot cone * cos(incidence) / r^2 (the render's light "
                  "model, the mesh's angle-weighted vertex normals), smoothed over smooth_px texels (Gaussian sigma)",
        "light": {k: v for k, v in light.to_dict().items() if k != "power_w"}, "T_world_cam": T_world_cam.tolist(),
        "level": "the median texel the light reaches keeps its value (rendering at the capture pose gives the "
                 "capture back up to the exposure, where the gain was not clamped)",
        "max_gain": MAX_GAIN, "smooth_px": options.delight_smooth, "stats": stats, "texture": folder.TEXTURE,
        "texture_lit": folder.TEXTURE_LIT})
    return section


def _working_distance(rc, path: CameraPath) -> float:
    """Median planar depth of the surface on the optical axis over the path's frames (0 when it sees none)."""
    depth = np.atleast_1d(rc.centre_depth(path.T_world_cam))
    depth = depth[np.isfinite(depth)]
    return float(np.median(depth)) if depth.size else 0.0


def _view_target(rc, path: CameraPath) -> np.ndarray:
    """The surface point on the optical axis in the path's middle frame (the mesh's median vertex if none)."""
    T = path.T_world_cam[path.frames // 2]
    depth = rc.centre_depth(T)
    if np.isfinite(depth):
        return T[:3, 3] + depth * T[:3, 2]
    return np.median(rc.vertices, axis=0)


def build_scene_folder(out_dir: Path, mesh, record: dict, options: SceneOptions, python: str | None = None,
                       config: SceneConfig | None = None) -> dict:
    """Build SCENE/scene.blend for ``mesh`` (its files already in out_dir) and write scene.json last.

    The objects of the scene configuration (``config``, else read from ``options``; see :func:`scene_config`)
    are added with their geometry in ``SCENE/objects/``. Blender runs in a fresh worker process
    (:func:`rgbd2scene.stages.blender.run_task`), which reads the geometry and texture files the scene model
    names.
    """
    t0 = time.perf_counter()
    if config is None:
        config = scene_config(options)
    rc = raycaster(mesh.vertices, mesh.triangles)
    texture = folder.TEXTURE if (out_dir / folder.TEXTURE).is_file() and mesh.uvs is not None else None
    capture = capture_camera(record, options) if options.path == CAPTURE_PATH else None
    t0_delight = time.perf_counter()
    delight = delight_scene_texture(out_dir, mesh, record, options, texture is not None and mesh.texture is not None)
    t_delight = time.perf_counter() - t0_delight
    desc = make_description(mesh.vertices, mesh.triangles, options, rc=rc, texture=texture, config=config,
                            capture=capture)
    coverage = path_coverage(mesh.vertices, mesh.triangles, desc.rig, desc.path, scale=0.5, rc=rc)
    timings = {"path_s": time.perf_counter() - t0 - t_delight, "delight_s": t_delight}
    objects_record = None
    if config is not None:
        t0 = time.perf_counter()
        intrinsics = record.get("capture", {}).get("intrinsics")
        tissue = Tissue(mesh.vertices, mesh.triangles, rc,
                        None if intrinsics is None else Intrinsics.from_dict(intrinsics).K)
        try:
            desc, objects_record = add_objects(desc, tissue, config, out_dir, seed=options.seed)
        except ConfigError as exc:
            raise _config_error(config, exc) from None
        timings["objects_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    blend = out_dir.resolve() / folder.SCENE_BLEND
    run_task(Task(BuildScene(str(out_dir.resolve()), desc.to_dict(), str(blend))), python=python,
             what="scene worker")
    timings["blend_s"] = time.perf_counter() - t0
    record = dict(record)
    record["scene"] = desc.to_dict()
    record["scene_options"] = to_record(options)
    record["delight"] = delight
    if delight["applied"]:
        record["files"] = {**record.get("files", {}), "texture_lit": folder.TEXTURE_LIT}
    record["coverage"] = {"min": float(coverage.min()), "mean": float(coverage.mean()),
                          "per_frame_left_right": coverage.round(4).tolist(), "check_scale": 0.5}
    if objects_record is not None:
        record["objects"] = objects_record
    record["blend"] = folder.SCENE_BLEND
    record.setdefault("timings", {}).update(timings)
    write_json(out_dir / folder.SCENE_JSON, record)
    return record


def load_mesh_folder(mesh_dir: str | Path, out_dir: Path):
    """Mesh (with UVs and texture) and scene.json record of a folder made by ``rgbd2scene mesh``.

    When ``out_dir`` differs, the folder's files are hard-linked there (copied across file systems), so the
    scene folder stands alone without taking the mesh's disk space again (a batch build makes one scene per
    sequence from each capture's mesh folder: about 60 MB saved per scene for a 640x480 capture).
    """

    src = Path(mesh_dir)
    record_path = src / folder.SCENE_JSON
    if not record_path.is_file() or not (src / folder.MESH).is_file():
        raise UserError(f"{src}: not a mesh folder made by 'rgbd2scene mesh' (needs scene.json and mesh.ply)")
    record = read_json_object(record_path, "scene.json")
    # from here on out_dir is a scene being built: it must not look complete until scene.json is rewritten
    (out_dir / folder.SCENE_JSON).unlink(missing_ok=True)
    mesh = read_ply(src / folder.MESH)
    lit = src / folder.TEXTURE_LIT  # a scene folder whose texture was de-lit: start from the lit texture
    texture_path = lit if lit.is_file() else src / folder.TEXTURE
    if texture_path.is_file():
        mesh.texture = read_image(texture_path)
        if mesh.texture is None:
            raise UserError(f"{texture_path}: not a readable texture image")
    if src.resolve() != out_dir.resolve():
        for name in folder.MESH_FOLDER_FILES:
            if (src / name).is_file():
                link_or_copy(src / name, out_dir / name)
        if lit.is_file():
            link_or_copy(lit, out_dir / folder.TEXTURE)
    record.pop("scene", None)
    record.pop("delight", None)
    if isinstance(record.get("files"), dict):
        record["files"].pop("texture_lit", None)
    return mesh, record
