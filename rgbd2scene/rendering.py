"""What a render is asked to deliver, shared by the render stage (no ``bpy``) and ``render/`` (Blender side).

One place declares the denoisers (option name -> Cycles' denoiser and whether OpenImageDenoise's guide
prefilter applies) and the fixed settings of the data render that gives Blender's ground-truth passes;
:mod:`rgbd2scene.stages.render` records them in dataset.json, :mod:`render.frames` applies them.
"""

from __future__ import annotations

from dataclasses import dataclass


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


DENOISERS = {d.name: d for d in (Denoiser("none", None), Denoiser("oidn", "OPENIMAGEDENOISE", prefilter=True),
                                 Denoiser("optix", "OPTIX"))}
#: OpenImageDenoise's guide prefilter (Cycles' ``denoising_prefilter``, lower case): ``accurate`` denoises the
#: albedo and normal guides apart (Blender's default, ~80 % of the denoiser's CPU time), ``fast`` filters them in
#: the same pass, ``none`` takes them as they are (benchmarks/results/render.md, section 6).
PREFILTERS = ("fast", "accurate", "none")

#: The data render of Blender's ground-truth passes (``--gt-source blender``; recorded in dataset.json): one
#: sample through the pixel centre (a pixel filter this narrow keeps it there), no bounces.
GT_SAMPLES, GT_FILTER_WIDTH_PX, GT_MAX_BOUNCES = 1, 0.01, 0
GT_RENDER = {"samples": GT_SAMPLES, "filter_width_px": GT_FILTER_WIDTH_PX, "max_bounces": GT_MAX_BOUNCES,
             "material_override": "black emission", "passes": ["Depth", "Normal", "Vector", "IndexOB"],
             "exr": "32-bit float, multilayer", "persistent_data": False}
