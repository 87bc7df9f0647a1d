"""Render worker: one bounded chunk of frames of a scene folder into a dataset folder (needs ``bpy``).

    python -m render.frames SCENE_DIR DATASET_DIR --start S --end E [--size WxH] [--samples N]
        [--gt all|none|depth,normals,...] [--device CPU|GPU] [--denoise none|oidn|optix] [--frames N]

``rgbd2scene.render_job`` runs it in fresh processes over bounded chunks (Blender grows in memory over
long renders); run by hand it does the same work for frames [S, E). Outputs that exist are not rendered
again (resume). Its stdout carries only progress lines for the parent's progress bar: ``frame 3 rgb
7.1s cpu 14.2s`` when the images of a frame are written, ``frame 3 done 7.4s cpu ... rgb ... gt ...
rss ...`` when all its files are, ``frame 3 skipped``; Blender's own chatter goes to stderr.

Each frame is rendered twice, both eyes each time (Blender multiview, PARALLEL, pivot LEFT):

1. **RGB**: the scene as built, ``--samples`` per pixel (adaptive), the usual pixel filter, no passes;
   Blender writes the 8-bit PNGs itself, with the scene's view transform, exactly as it saves renders
   (no numpy re-encoding of a linear Combined pass).
2. **Data** (only when ground truth is asked for): 1 sample per pixel, pixel filter width 0.01 (the one
   sample goes through the pixel centre, +-0.005 px), ``max_bounces`` 0, no denoising, a black emission
   material override (no lights, BSDFs or subsurface are evaluated: the geometry alone decides every
   pass), passes Depth, Normal, Vector and Object Index written as a 32-bit multilayer EXR. Those passes
   are then exact per pixel centre: no anti-aliasing blends two surfaces (Depth and Object Index of the
   RGB render are first-sample values, but with the RGB render's wide pixel filter that sample is not at
   the pixel centre; Normal and Vector are averaged over samples). The override also keeps shading
   tricks out of the Normal pass (the Principled BSDF bends normals at grazing angles): the normals are
   the mesh's interpolated normals, like the depth is the mesh's depth.

The passes become the section-3 maps in :func:`rgbd2scene.groundtruth.gt_from_passes` and are written
by :mod:`rgbd2scene.dataset` (atomic). Temporary files live in ``DATASET/.work`` and are removed.

Cost (2 cores, 512x256, the bundled sample's 307k-vertex mesh, wet-tissue material, defaults 1 spp + OIDN):
RGB about 1.8 s per stereo frame; the ground truth adds about 0.16 s (data render with its BVH rebuilds,
EXR read, conversion, npz): see benchmarks/results/render.md. To keep it there: all RGB renders of a chunk run first,
then all data renders (switching configuration per frame made Cycles rebuild its scene twice per
frame), persistent data is on, settings are only assigned when they change, and frame i's passes are
converted and compressed in a thread while frame i+1's data render runs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import time
import traceback
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from rgbd2scene.capture.camera import Intrinsics
from rgbd2scene.cli import parse_size
from rgbd2scene.conventions import opencv_pose_from_blender
from rgbd2scene.dataset import layout as ds
from rgbd2scene.groundtruth.passes import MAPS, gt_from_passes, parse_maps, passes_needed
from rgbd2scene.scene.model import SceneDescription
from rgbd2scene.scene.rig import StereoRig
from rgbd2scene.stages.render import DEFAULT_DENOISE, DEFAULT_SAMPLES

#: Pixel filter width of the data render: small enough that its one sample is the pixel centre.
DATA_FILTER_WIDTH = 0.01
GT_MATERIAL = "rgbd2scene_gt_override"
VIEWS = {"left": "_L", "right": "_R"}
#: Pass name in the EXR channel names (``<ViewLayer>.<pass>.<channel>``) -> our pass key.
EXR_PASSES = {"depth": ("Depth", "Z"), "normal": ("Normal", "XYZ"), "vector": ("Vector", "XYZW"),
              "index": ("Object Index", "X")}
DENOISERS = {"none": None, "oidn": "OPENIMAGEDENOISE", "openimagedenoise": "OPENIMAGEDENOISE",
             "optix": "OPTIX"}


class WorkerError(RuntimeError):
    pass


# --- scene description ---------------------------------------------------------------------------------

def load_description(scene_dir: Path, bpy_scene=None) -> SceneDescription:
    """The scene's description: ``scene.json["scene"]``, else the blend's ``scene["rgbd2scene"]``."""
    record_path = scene_dir / "scene.json"
    if record_path.is_file():
        record = json.loads(record_path.read_text())
        if isinstance(record, dict) and isinstance(record.get("scene"), dict):
            return SceneDescription.from_dict(record["scene"])
    if bpy_scene is not None and "rgbd2scene" in bpy_scene.keys():
        return SceneDescription.from_dict(json.loads(bpy_scene["rgbd2scene"]))
    raise WorkerError(f"{scene_dir}: no scene description in scene.json['scene'] nor in scene.blend")


# --- Blender set-up --------------------------------------------------------------------------------------

def _set_device(bpy, scene, device: str) -> str:
    device = device.upper()
    if device == "CPU":
        scene.cycles.device = "CPU"
        return "CPU"
    if device != "GPU":
        raise WorkerError(f"--device must be CPU or GPU, got {device!r}")
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for kind in ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL"):
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
    raise WorkerError("--device GPU: Cycles found no GPU (OptiX, CUDA, HIP, oneAPI or Metal)")


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

    def __init__(self, bpy, scene_dir: Path, out_dir: Path, size, samples: int, adaptive: bool,
                 denoise: str | None, device: str, seed: int, threads: int, maps: tuple[str, ...],
                 frames: int | None, persistent_data: bool = True):
        self.bpy = bpy
        self.out_dir = out_dir
        blend = scene_dir / "scene.blend"
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        scene = self.scene = bpy.context.scene
        self.description = load_description(scene_dir, scene)
        camera = scene.camera or bpy.data.objects.get("Endoscope")
        if camera is None or camera.type != "CAMERA":
            raise WorkerError(f"{blend}: the scene has no camera")
        self.camera = camera
        self.frames = int(frames) if frames else self.description.path.frames

        # intrinsics (resized if asked) -> resolution, lens, shift, pixel aspect
        from render.scene_builder import set_intrinsics

        intr: Intrinsics = self.description.rig.intrinsics
        if size is not None:
            intr = intr.resized(*size)
        set_intrinsics(scene, camera, intr)
        self.intrinsics = intr
        self.K = intr.K

        # the stereo pair must be the rectified one of the contract
        stereo = camera.data.stereo
        if not scene.render.use_multiview or scene.render.views_format != "STEREO_3D":
            raise WorkerError(f"{blend}: the scene is not a stereo (multiview STEREO_3D) scene")
        if stereo.convergence_mode != "PARALLEL" or stereo.pivot != "LEFT":
            raise WorkerError(f"{blend}: stereo must be PARALLEL with pivot LEFT, found "
                              f"{stereo.convergence_mode} / {stereo.pivot}")
        for view in scene.render.views:
            view.use = view.name in VIEWS
        self.baseline = float(stereo.interocular_distance)
        if abs(self.baseline - self.description.rig.baseline) > 1e-9:
            print(f"warning: blend baseline {self.baseline} differs from scene.json "
                  f"{self.description.rig.baseline}; using the blend's", file=sys.stderr)
        self.rig = StereoRig(intr, self.baseline)

        scene.render.engine = "CYCLES"
        scene.render.use_motion_blur = False  # the Vector pass needs it off
        scene.render.use_file_extension = True
        # keep Cycles' scene between renders: back-to-back RGB renders of a chunk then skip the BVH build
        # (sync 0.004 s instead of 0.1-0.2 s per frame on a 300k-vertex mesh); the data render's material
        # override still makes it rebuild, but less (measured 0.17 vs 0.28 s). Depth, flow and ids come
        # out bit-identical, normals within 2e-7.
        scene.render.use_persistent_data = bool(persistent_data)
        scene.render.image_settings.views_format = "INDIVIDUAL"
        self.device = _set_device(bpy, scene, device)
        if threads and threads > 0:
            scene.render.threads_mode = "FIXED"
            scene.render.threads = int(threads)
        self.samples, self.adaptive, self.seed = int(samples), bool(adaptive), int(seed)
        self.denoiser = DENOISERS[(denoise or "none").lower()]
        self.rgb_filter_width = float(scene.cycles.filter_width)
        self.rgb_max_bounces = int(scene.cycles.max_bounces)
        self.maps = maps
        self.passes = passes_needed(maps)
        self.gt_material = _gt_material(bpy) if maps else None
        self.view_layer = scene.view_layers[0]
        for layer in scene.view_layers[1:]:
            layer.use = False
        self.images_at_start = {img.name for img in bpy.data.images}
        self.work = out_dir / ds.WORK_DIR
        self.work.mkdir(parents=True, exist_ok=True)
        self.tag = f"{os.getpid()}"

        # objects tracked in object_ids / object_poses: the description's, found by pass_index
        self.tracked = []
        for obj in self.description.objects:
            match = [o for o in scene.objects if o.pass_index == obj.id and o.type in ("MESH", "EMPTY")]
            match = match or [o for o in scene.objects if o.name == obj.name]
            self.tracked.append((obj.id, match[0] if match else None))

    # -- configurations --
    # Only changed values are assigned: any assignment tags Blender data as updated, and with persistent
    # data an updated material (override) makes Cycles rebuild the geometry and its BVH.

    def configure_rgb(self) -> None:
        sc, cy, vl = self.scene, self.scene.cycles, self.view_layer
        _apply([(cy, "samples", self.samples), (cy, "use_adaptive_sampling", self.adaptive),
                (cy, "filter_width", self.rgb_filter_width), (cy, "max_bounces", self.rgb_max_bounces),
                (cy, "use_denoising", self.denoiser is not None), (cy, "seed", self.seed),
                (cy, "use_animated_seed", True),  # a different (reproducible) noise pattern per frame
                (vl, "material_override", None), (vl, "use_pass_combined", True),
                (vl, "use_pass_z", False), (vl, "use_pass_normal", False), (vl, "use_pass_vector", False),
                (vl, "use_pass_object_index", False)])
        if self.denoiser:
            _apply([(cy, "denoiser", self.denoiser)])
        s = sc.render.image_settings
        _apply([(s, "media_type", "IMAGE"), (s, "file_format", "PNG"), (s, "color_mode", "RGB"),
                (s, "color_depth", "8"), (s, "views_format", "INDIVIDUAL")])

    def configure_data(self) -> None:
        sc, cy, vl, p = self.scene, self.scene.cycles, self.view_layer, self.passes
        _apply([(cy, "samples", 1), (cy, "use_adaptive_sampling", False),
                (cy, "filter_width", DATA_FILTER_WIDTH),
                (cy, "max_bounces", 0), (cy, "use_denoising", False), (cy, "seed", 0),
                (cy, "use_animated_seed", False), (vl, "material_override", self.gt_material),
                (vl, "use_pass_z", True), (vl, "use_pass_normal", "normal" in p),
                (vl, "use_pass_vector", "vector" in p), (vl, "use_pass_object_index", "index" in p)])
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

    def pose_left(self) -> np.ndarray:
        return opencv_pose_from_blender(np.array(self.camera.matrix_world, dtype=np.float64))

    def object_poses(self) -> tuple[np.ndarray, np.ndarray]:
        ids, poses = [], []
        for oid, obj in self.tracked:
            ids.append(oid)
            poses.append(np.array(obj.matrix_world, dtype=np.float64) if obj is not None
                         else np.full((4, 4), np.nan))
        return np.asarray(ids, np.uint16), np.asarray(poses, np.float64).reshape(-1, 4, 4)

    def render_rgb(self, index: int) -> None:
        self.configure_rgb()
        files = self._render(self.work / f"{self.tag}_{ds.frame_name(index)}_rgb", ".png")
        for eye, src in files.items():
            ds.install_file(src, ds.frame_paths(self.out_dir, eye, index).rgb)

    def render_data(self, index: int) -> dict:
        """The data render of the current frame (Blender side): EXR files, poses, tracked objects."""
        self.configure_data()
        files = self._render(self.work / f"{self.tag}_{ds.frame_name(index)}_data", ".exr")
        T_left = self.pose_left()
        ids, obj_poses = self.object_poses()
        poses = {"left": T_left, "right": self.rig.right_pose(T_left)}
        return {"index": index, "files": files, "poses": poses, "object_ids": ids, "object_poses": obj_poses}

    def write_gt(self, job: dict) -> None:
        """Passes -> ground truth -> npz of both eyes; removes the EXRs. No ``bpy``: runs in a thread."""
        index = job["index"]
        try:
            for eye, path in job["files"].items():
                passes = read_passes(path, self.passes | {"depth"})
                gt = gt_from_passes(passes["depth"], passes.get("normal"), passes.get("vector"),
                                    passes.get("index"), self.K, job["poses"][eye], self.baseline,
                                    first=index == 0, last=index == self.frames - 1,
                                    object_ids=job["object_ids"], object_poses=job["object_poses"],
                                    maps=self.maps)
                ds.write_gt(ds.frame_paths(self.out_dir, eye, index).gt, gt)
        finally:
            for path in job["files"].values():
                path.unlink(missing_ok=True)

    def render_gt(self, index: int) -> None:
        self.write_gt(self.render_data(index))

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


# --- main ------------------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m render.frames", description=__doc__.splitlines()[0])
    p.add_argument("scene_dir", type=Path)
    p.add_argument("dataset_dir", type=Path)
    p.add_argument("--start", type=int, default=0, help="first frame (default 0)")
    p.add_argument("--end", type=int, default=None, help="one past the last frame (default: all)")
    p.add_argument("--frames", type=int, default=None,
                   help="frames in the whole dataset (its last frame has NaN forward flow); default: "
                        "dataset.json's, else the path's")
    p.add_argument("--size", type=parse_size, default=None, help="WxH (default: the scene's)")
    p.add_argument("--samples", type=int, default=DEFAULT_SAMPLES,
                   help=f"RGB samples per pixel (default {DEFAULT_SAMPLES})")
    p.add_argument("--no-adaptive", action="store_true", help="turn adaptive sampling off")
    p.add_argument("--denoise", default=DEFAULT_DENOISE, choices=sorted(DENOISERS),
                   help=f"RGB denoiser (default {DEFAULT_DENOISE})")
    p.add_argument("--gt", default="all", help=f"all, none or a comma list of {', '.join(MAPS)}, flow")
    p.add_argument("--device", default="CPU", choices=("CPU", "GPU", "cpu", "gpu"))
    p.add_argument("--seed", type=int, default=0, help="Cycles seed (animated per frame)")
    p.add_argument("--threads", type=int, default=0, help="render threads (0: all cores)")
    p.add_argument("--no-persistent-data", action="store_true",
                   help="rebuild Cycles' scene data (BVH) for every render instead of keeping it")
    p.add_argument("--describe", action="store_true",
                   help="print the scene description (JSON, one line) on stdout and exit")
    return p


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # stdout is the progress channel: keep it for our lines and send everything else (Blender's C-level
    # prints included) to stderr
    sys.stdout.flush()
    progress = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)

    def say(line: str) -> None:
        progress.write(line + "\n")
        progress.flush()

    try:
        maps = parse_maps(args.gt)
        scene_dir, out_dir = args.scene_dir.resolve(), args.dataset_dir.resolve()
        if not (scene_dir / "scene.blend").is_file():
            raise WorkerError(f"{scene_dir}: no scene.blend")
        frames = args.frames
        if frames is None and (out_dir / ds.DATASET_JSON).is_file():
            frames = json.loads((out_dir / ds.DATASET_JSON).read_text()).get("frames")
        t0 = time.perf_counter()
        import bpy

        if args.describe:
            bpy.ops.wm.open_mainfile(filepath=str(scene_dir / "scene.blend"))
            say(json.dumps(load_description(scene_dir, bpy.context.scene).to_dict()))
            return 0

        renderer = Renderer(bpy, scene_dir, out_dir, args.size, args.samples, not args.no_adaptive,
                            args.denoise, args.device, args.seed, args.threads, maps, frames,
                            persistent_data=not args.no_persistent_data)
        end = renderer.frames if args.end is None else min(args.end, renderer.frames)
        say(f"ready {time.perf_counter() - t0:.3f}s device {renderer.device}")
        indices = range(max(args.start, 0), end)
        need_rgb = [i for i in indices if not ds.rgb_done(out_dir, i)]
        need_gt = [i for i in indices if maps and not ds.gt_done(out_dir, i)]
        for i in sorted(set(indices) - set(need_rgb) - set(need_gt)):
            say(f"frame {i} skipped")
        # Two phases: every RGB render of the chunk, then every data render. Switching between the two
        # configurations makes Cycles rebuild its scene (the material override changes the shaders), so
        # alternating them per frame costs ~0.1 s more per frame than running each kind back to back.
        spent: dict[int, tuple[float, float]] = {}
        for index in need_rgb:
            t0, c0 = time.perf_counter(), _cpu_s()
            renderer.scene.frame_set(index)
            renderer.render_rgb(index)
            renderer.free_images()
            spent[index] = (time.perf_counter() - t0, _cpu_s() - c0)
            if index in need_gt:  # the frame is finished by the data render below
                say(f"frame {index} rgb {spent[index][0]:.3f}s cpu {spent[index][1]:.3f}s")
            else:
                say(f"frame {index} done {spent[index][0]:.3f}s cpu {spent[index][1]:.3f}s "
                    f"rgb {spent[index][0]:.3f}s gt 0.000s rss {_rss_mb():.0f}MB")
        # The data phase is pipelined: frame i's passes are converted and compressed in a thread while
        # Blender renders frame i+1 (the data render leaves a core idle: BVH builds, 1 sample).
        t_mark, c_mark = time.perf_counter(), _cpu_s()
        with ThreadPoolExecutor(max_workers=1) as pool:
            pending: list[tuple[int, Future]] = []
            for index in need_gt + [None]:
                if index is not None:
                    renderer.scene.frame_set(index)
                    job = renderer.render_data(index)
                    renderer.free_images()
                    pending.append((index, pool.submit(renderer.write_gt, job)))
                while pending and (index is None or len(pending) > 1):
                    done_index, future = pending.pop(0)
                    future.result()
                    now, cpu = time.perf_counter(), _cpu_s()
                    t_gt, c_gt = now - t_mark, cpu - c_mark  # this frame's share of the phase
                    t_mark, c_mark = now, cpu
                    t_rgb, c_rgb = spent.get(done_index, (0.0, 0.0))
                    say(f"frame {done_index} done {t_rgb + t_gt:.3f}s cpu {c_rgb + c_gt:.3f}s "
                        f"rgb {t_rgb:.3f}s gt {t_gt:.3f}s rss {_rss_mb():.0f}MB")
        try:
            renderer.work.rmdir()  # only when empty: another worker may still use it
        except OSError:
            pass
        return 0
    except WorkerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Exception:  # noqa: BLE001 - report everything to the parent, which shows the tail
        traceback.print_exc()
        return 1
    finally:
        progress.close()


if __name__ == "__main__":
    sys.exit(main())
