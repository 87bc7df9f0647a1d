"""What a render is asked to deliver, shared by the render stage (no ``bpy``) and ``render/`` (Blender side).

One place declares the engines (``--engine``: Cycles on the CPU or a GPU back-end), the denoisers (option
name -> Cycles' denoiser and whether OpenImageDenoise's guide prefilter applies), the fixed settings of the
data render that gives Blender's ground-truth passes, and :class:`RenderOptions`, every setting of a render;
:mod:`rgbd2scene.stages.render` validates them and records them in dataset.json, :mod:`render.frames`
applies them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

from rgbd2scene.environment import EnvironmentOptions
from rgbd2scene.groundtruth.passes import parse_maps
from rgbd2scene.options import OptionError, option
from rgbd2scene.sensor import SensorOptions


@dataclass(frozen=True)
class Denoiser:
    """A denoiser the RGB render may use.

    Attributes
    ----------
    name
        The option value (``--denoise``).
    blender
        Cycles' ``denoiser`` enum, or None: no denoising.
    prefilter
        Whether ``--prefilter`` applies (OpenImageDenoise cleans its albedo and normal guides first).
    """

    name: str
    blender: str | None
    prefilter: bool = False


@dataclass(frozen=True)
class Engine:
    """A renderer the RGB render may run on; every engine delivers the same passes (the linear Combined image,
    and Depth where the environment needs ray lengths; the ground truth comes from the scene model, or from
    the Cycles CPU data render of ``--gt-source blender``).

    Attributes
    ----------
    name
        The option value (``--engine``).
    blender
        Blender's render engine.
    backends
        Cycles' GPU compute device types to try, in order (empty: the CPU).
    """

    name: str
    blender: str
    backends: tuple[str, ...] = ()

    @property
    def gpu(self) -> bool:
        return bool(self.backends)


#: Eevee is left out: it renders headless here only through software EGL, ~15 s for a tiny frame of the default
#: cube (/work/shared/NOTES.md), slower than Cycles on the CPU.
ENGINES = {e.name: e for e in (Engine("cycles", "CYCLES"),
                               Engine("cycles-gpu", "CYCLES", ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")),
                               Engine("cycles-optix", "CYCLES", ("OPTIX",)), Engine("cycles-cuda", "CYCLES", ("CUDA",)),
                               Engine("cycles-hip", "CYCLES", ("HIP",)))}

DENOISERS = {d.name: d for d in (Denoiser("none", None), Denoiser("oidn", "OPENIMAGEDENOISE", prefilter=True),
                                 Denoiser("optix", "OPTIX"))}
#: OpenImageDenoise's guide prefilter (Cycles' ``denoising_prefilter``, lower case): ``accurate`` denoises the
#: albedo and normal guides apart (Blender's default, ~80 % of the denoiser's CPU time), ``fast`` filters them in
#: the same pass, ``none`` takes them as they are (benchmarks/results/profile.md; render.md, section 7).
PREFILTERS = ("fast", "accurate", "none")
#: OpenImageDenoise's network (Cycles' ``denoising_quality``, lower case): ``high`` (Blender's default), ``balanced``
#: (the same network and cost as ``high`` on the CPU: identical images) and ``fast``, a smaller network at about half
#: the denoiser's CPU time (benchmarks/results/render.md, section 9).
DENOISE_QUALITIES = ("fast", "balanced", "high")

#: The data render of Blender's ground-truth passes (``--gt-source blender``; recorded in dataset.json): one
#: sample through the pixel centre (a pixel filter this narrow keeps it there), no bounces.
GT_SAMPLES, GT_FILTER_WIDTH_PX, GT_MAX_BOUNCES = 1, 0.01, 0
GT_RENDER = {"samples": GT_SAMPLES, "filter_width_px": GT_FILTER_WIDTH_PX, "max_bounces": GT_MAX_BOUNCES,
             "material_override": "black emission", "passes": ["Depth", "Normal", "Vector", "IndexOB"],
             "exr": "32-bit float, multilayer", "persistent_data": False}

GT_SOURCES = ("model", "blender")
#: RGB defaults: 1 sample per pixel denoised with OpenImageDenoise's ``fast`` network, its guides prefiltered
#: ``fast``, and Cycles' blue-noise sampling pattern: 35.4-37.3 dB / SSIM 0.954-0.964 against 256 samples at 512x256
#: on three frames (tuned on one, checked on two), at 1/6.9 of the CPU time of a 16-sample render of the same scene
#: with all ground truth (issue16.md section 3). The ``fast`` network (session 7) halves the denoiser's CPU time
#: (0.18 instead of 0.34 CPU s per 512x256 image) for equal or better PSNR (+0.0 to +0.8 dB) and SSIM within 0.0025,
#: but keeps about 0.15 less of the pixel-scale texture (the sweep's detail measure) than ``high``, and on metal
#: (the instrument scene) scores 0.15-0.27 dB / 0.005 SSIM lower: a trade for the cost, which
#: ``--denoise-quality high`` undoes (the previous default, 1/5.6 of the 16-sample render's CPU time). Blue noise
#: instead of the blend's tabulated Sobol pattern: +0.2 dB after denoising, 0.5 dB less noise at 16 samples, same
#: cost. No setting within six times less than the 16-sample render reaches 40 dB / 0.97: OIDN smears the tissue's
#: pixel-scale texture and the coat's glints on it (4 spp: 37-40 dB; denoising diffuse and glossy apart: +0.3 dB,
#: +0.007 SSIM for two denoiser runs; benchmarks/results/render.md sections 8-9).
DEFAULT_SAMPLES = 1
DEFAULT_DENOISE = "oidn"
DEFAULT_PREFILTER = "fast"
DEFAULT_DENOISE_QUALITY = "fast"
RGB_SAMPLING_PATTERN = "BLUE_NOISE"
DEFAULT_CHUNK = 25


#: Memory one pixel of a stereo frame takes while rendering: Cycles' float buffers of both views (combined,
#: denoising albedo and normal, passes) and the ground truth's per-pixel rays, hits and maps, with room to spare.
BYTES_PER_PIXEL = 600


def render_memory_bytes(width: int, height: int) -> int:
    """An estimate of the memory a render at width x height needs (:data:`BYTES_PER_PIXEL`)."""
    return int(width) * int(height) * BYTES_PER_PIXEL


def machine_memory_bytes() -> int | None:
    """This machine's physical memory (None where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def parse_size(text: str) -> tuple[int, int]:
    """``"512x256"`` -> (512, 256); ValueError when it is not two positive integers."""
    try:
        w, h = (int(x) for x in str(text).lower().split("x"))
    except ValueError:
        raise ValueError(f"size must look like 512x256, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"size must be positive, got {text!r}")
    return w, h


@dataclass
class RenderOptions:
    """Every setting of the render stage (CLI flags, batch keys, the task file and dataset.json's record)."""

    frames: int | None = option(None, "dataset length: the first N frames of the path (default all)")
    size: tuple[int, int] | None = option(None, "image size WxH (default the scene's; K is rescaled)",
                                          parse=parse_size, metavar="WxH")
    gt: str = option("all", "maps: all, none, or a list of depth,disparity,normals,flow,segmentation "
                     "(default all)", resume=True)
    start: int | None = option(None, "first frame of this chunk (default 0)")
    end: int | None = option(None, "end (exclusive) of this chunk (default the last frame)")
    samples: int = option(DEFAULT_SAMPLES, "RGB samples per pixel", resume=True)
    adaptive: bool = option(True, "turn off adaptive sampling", resume=True)
    denoise: str = option(DEFAULT_DENOISE, "denoiser: none, oidn, optix (the ground truth never sees it)",
                          resume=True)
    prefilter: str = option(DEFAULT_PREFILTER, "oidn: how its albedo and normal guides are cleaned: fast, accurate "
                            "(Blender's default, about 4x the cost) or none", choices=PREFILTERS, resume=True)
    denoise_quality: str = option(DEFAULT_DENOISE_QUALITY, "oidn: its network: fast (about half the denoiser's "
                                  "cost), balanced or high (Blender's default)", choices=DENOISE_QUALITIES,
                                  resume=True)
    engine: str = option("cycles", "the RGB render's engine: cycles (CPU), cycles-gpu (OptiX, CUDA, HIP, oneAPI or "
                         "Metal, the first found), cycles-optix, cycles-cuda or cycles-hip", choices=tuple(ENGINES),
                         resume=True)
    threads: int = option(0, "render threads (0: all cores)")
    chunk: int = option(DEFAULT_CHUNK, "frames per worker process (Blender grows in memory over long renders)")
    seed: int = option(0, "Cycles seed (animated per frame)", resume=True)
    persistent_data: bool = option(True, "keep Cycles' scene data (BVH) between the renders of a chunk",
                                   cli=False)
    gt_source: str = option("model", "where the ground truth comes from: model (ray casting the scene model along "
                            "each pixel's ray, no data render) or blender (Blender's passes: the independent "
                            "cross-check; pinhole rectified rigs only)", choices=GT_SOURCES, resume=True)
    rectify: bool = option(False, "render the rectified pair of a raw scope (distortion or unequal eyes) as "
                           "cv2.stereoRectify (alpha 0) defines it, with disparity; default: the raw pair, as the "
                           "scope delivers it, with correspondence", resume=True)
    gt_only: bool = option(False, "write (or rewrite) only the ground truth of the frames, from the scene model "
                           "without Blender: regenerates or extends an existing dataset's npz files")
    view_culling: bool = option(True, "data renders sync only the triangles the frame's eyes see and their "
                                "neighbours (the same passes, bit for bit; off: the whole scene)", cli=False)
    sensor: SensorOptions = option(SensorOptions(), "the scope camera's exposure, sensor and optics effects "
                                   "(RGB only)", resume=True)
    environment: EnvironmentOptions = option(EnvironmentOptions(), "what fills the space in front of the scope "
                                             "(RGB only)", resume=True)

    def validated(self) -> RenderOptions:
        """A normalised copy (map list, lower-case denoiser); :class:`OptionError` if bad."""
        try:
            maps = parse_maps(self.gt)
        except ValueError as exc:
            raise OptionError("gt", str(exc)) from None
        denoise = (self.denoise or "none").lower()
        if denoise not in DENOISERS:
            raise OptionError("denoise", f"choose one of {', '.join(DENOISERS)}, got {self.denoise!r}")
        for name, choices in (("engine", ENGINES), ("prefilter", PREFILTERS), ("denoise_quality", DENOISE_QUALITIES)):
            if getattr(self, name) not in choices:
                raise OptionError(name, f"choose one of {', '.join(choices)}, got {getattr(self, name)!r}")
        for name in ("samples", "chunk"):
            if int(getattr(self, name)) < 1:
                raise OptionError(name, f"must be at least 1, got {getattr(self, name)}")
        size = None
        if self.size is not None:
            size = tuple(int(v) for v in self.size)
            if len(size) != 2 or min(size) <= 0:
                raise OptionError("size", f"must be positive, got {'x'.join(map(str, size))}")
            need, have = render_memory_bytes(*size), machine_memory_bytes()
            if have and need > have:
                raise OptionError("size", f"{size[0]}x{size[1]} needs about {need / 2**30:,.0f} GiB to render "
                                  f"(estimate: {BYTES_PER_PIXEL} bytes per pixel), more than this machine's "
                                  f"{have / 2**30:.0f} GiB")
        nested = {}
        for name, cls in (("sensor", SensorOptions), ("environment", EnvironmentOptions)):
            value = getattr(self, name)
            try:
                nested[name] = (cls.from_dict(value) if isinstance(value, dict) else value).validated()
            except OptionError as exc:
                raise OptionError(f"{name}.{exc.name}", exc.message) from None
        return replace(self, gt=",".join(maps) or "none", denoise=denoise, size=size,
                       samples=int(self.samples), chunk=int(self.chunk), seed=int(self.seed), **nested)

    @property
    def maps(self) -> tuple[str, ...]:
        return parse_maps(self.gt)

    @property
    def gt_from_model(self) -> bool:
        """Whether the ground truth is ray-cast from the scene model (no data render in Blender)."""
        return bool(self.maps) and self.gt_source == "model"
