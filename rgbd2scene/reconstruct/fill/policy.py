"""The hole-filling policy: :func:`fill_depth` decides which pixels to fill and, for ``auto``, how.

Methods (``FILL_METHODS``)
--------------------------
``inpaint``, ``colorization``, ``nyu_colorization``, ``biharmonic``, ``background``: one solver of
:mod:`rgbd2scene.reconstruct.fill.solvers` for every interior hole; ``auto`` (the default) chooses per
hole and per hole row (below); ``none`` fills nothing. Whatever the method, the same pixels are filled
(:func:`rgbd2scene.reconstruct.fill.holes.classify_holes`): every hole pixel on the captured surface.
Interior holes are filled by the method; then the sensor's border band (and any hole that only the band
separates from the surface) by a biharmonic fill from the surface and the filled interior, which
continues the surface's slope to the image edge (``fill_border=False`` leaves the band NaN). On the
bundled sample's own 8 px band it is about as good as a harmonic fill (0.83 mm against 0.78 mm; copying
the nearest depth: 1.48 mm), and on the wider bands of real masks laid onto other captures (tune split
of the benchmark) clearly better: worst transplanted row 1.15 times the best plain solver, not 1.51.
Pixels outside the captured surface stay NaN. A hole's size plays no part.

What ``auto`` does
------------------
1. **Occlusion shadows** (:func:`~rgbd2scene.reconstruct.fill.holes.shadow_pixels`): a horizontal run
   of hole pixels across a depth step, no wider than the shadow the sensor casts there,
   fx * b * (1/z_near - 1/z_far) + 1 px, on the side the sensor casts it (``Sensor.shadow_baselines``),
   takes the depth of its far end (:func:`~rgbd2scene.reconstruct.fill.solvers.fill_row_background`):
   the shadow lies on the far surface. Time-of-flight sensors and ``sensor="none"`` cast no shadows:
   nothing is filled this way. For the Kinect v1 model, in the real TUM frame the step-bridging hole
   runs left of a near surface have a median width of 0.96 times the 7.5 cm bound (shadows), those
   right of it 3.6 times (mostly dropouts), so wider runs are not taken for shadows (a slack of 2 or
   3 px instead of 1 recognised more of the bundled sample's shadows but took more of its dropouts
   for shadows, and lost more there than it gained). On the simulated shadows of the benchmark the
   row fill is twice as accurate as a smooth fill from the far side (harmonic, ``background``).
2. **Holes with a depth step and holes wider than ``small_radius``** (an inscribed disk of radius above
   2.5 % of the shorter side): the mean of the colorization and the biharmonic fills (biharmonic alone
   without RGB), the biharmonic one clipped to the hole's rim depth range where the hole bridges a step
   (:func:`~rgbd2scene.reconstruct.fill.solvers.clip_to_rim`): a thin plate across a depth step overshoots
   beyond both sides, while on a smooth dome its curvature is the surface's (tuning split: geometric mean
   over its rows 1.065 -> 1.053, its captures with the colour removed 1.174 -> 1.098; rows above 1.10
   8 -> 8 and 5 -> 4). Neither fill wins everywhere (colour edges follow depth edges in rooms, not on
   textured or specular tissue), and a self-validation on copies of the holes could not tell them apart
   (3. below). On the benchmark's tuning split their mean was within 3 % of the better of the two, or
   better, on every family but two: specular highlights and the bundled sample's own shadows. Highlights
   are therefore not guided by colour: a hole at least half of whose pixels are bright, unsaturated and
   brighter than the surface around it (:func:`~rgbd2scene.reconstruct.fill.holes.highlight_pixels`) gets
   the smooth fill of 3. below, whatever its width. Its colour is the light's, not the surface's, and a
   uniform white patch matches whatever white surface lies next to it (the TUM frame's desk: tuning row
   3.31 -> 1.18 times the best plain solver, no other tuning row changed). Brighter than its rim, and not
   merely bright: a hole in a white wall is as bright as the wall around it, and colour helps there (a
   rule on brightness alone took the Redwood frames' walls for highlights).
3. **Narrow holes without a step, and highlights**: a harmonic or a biharmonic fill, whichever had
   the smaller error on copies of these holes laid onto valid depth nearby (:func:`choose_smooth_fill`,
   :func:`~rgbd2scene.reconstruct.fill.holes.hole_copies`: each hole shifted by its own size, up to
   ``copies`` times, where the copy lands on valid depth away from other holes). Harmonic averages a
   sensor's noise; biharmonic is exact on smooth noise-free depth (depth from CT or a renderer), so the
   depth itself decides rather than the sensor setting. The choice is made once per image, on the
   copies of all narrow holes pooled: noise is the sensor's, the same across the image, and choosing
   per hole (each hole's error pulled towards the image's by 200 px' worth) did worse on the tuning
   split. On the tuning split the choice is about neutral (geometric mean over its rows 1.114 against
   1.118 with harmonic always); it is meant for noise-free depth, which that split lacks. Without a
   copy that fits, harmonic (the earlier rule). Tried and not used: choosing among colorization,
   biharmonic, harmonic and their mean per hole on such copies (tuning split 1.30 against 1.12: a copy
   sees neither the hole's colour, e.g. a highlight's, nor what made the hole: holes sit at depth edges
   and on dark or glancing surfaces, copies on plain surface; and it doubled the time); and dropping
   the colour guidance for holes whose pixels are merely bright and unsaturated: on the report run
   it also took the white walls of the Redwood frames for highlights (blobs rows 1.30 -> 2.12),
   hence the test against the hole's rim in 2.
``FillResult.method`` names what was used, e.g. ``"auto: background+colorization+biharmonic+harmonic"``
(``FillResult.stats["auto_pixels"]``: how many pixels each filled; colorization counts the pixels it was
averaged into).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage as ndi

from rgbd2scene.capture.sensors import KINECT_V1, Sensor
from rgbd2scene.reconstruct.fill.holes import (
    classify_holes,
    components,
    highlight_pixels,
    hole_copies,
    shadow_pixels,
    step_runs,
    valid_depth,
)
from rgbd2scene.reconstruct.fill.solvers import (
    as_depth,
    clip_to_rim,
    fill_background,
    fill_biharmonic,
    fill_colorization,
    fill_harmonic,
    fill_inpaint,
    fill_nyu_colorization,
    fill_row_background,
    grey_levels,
)

FILL_METHODS = ("auto", "inpaint", "colorization", "nyu_colorization", "biharmonic", "background", "none")

#: Kinect v1 focal length at 640 px width (PrimeSense default intrinsics): the default fx.
KINECT_FX_640 = 525.0


@dataclass
class FillResult:
    """Outcome of :func:`fill_depth`.

    Attributes
    ----------
    depth : float32 (H, W) metres; NaN only outside the captured surface (and in holes with no
        valid pixel around them).
    filled : bool (H, W), pixels that were holes and now hold a value.
    method : the method actually used (for ``auto`` what it chose, e.g. ``"auto: background+harmonic"``).
    settings : every setting, JSON-serialisable.
    stats : JSON-serialisable statistics (fractions of the image, hole counts, seconds).
    """

    depth: np.ndarray
    filled: np.ndarray
    method: str
    settings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


def fill_depth(
    depth: np.ndarray,
    rgb: np.ndarray | None = None,
    method: str = "auto",
    *,
    sensor: Sensor = KINECT_V1,
    fx: float | None = None,
    border_width: int | None = None,
    fill_border: bool = True,
    min_radius: float | None = None,
    step: float = 0.04,
    small_radius: float | None = None,
    copies: int = 3,
    inpaint_radius: float = 5.0,
    inpaint_algorithm: str = "ns",
) -> FillResult:
    """Fill the holes of a depth map that lie on the captured surface (module docstring).

    Parameters
    ----------
    depth : float32 (H, W) metres, NaN = hole (non-positive values are holes too).
    rgb : uint8 (H, W, 3) registered colour image (colorization needs it; optional otherwise).
    method : one of ``FILL_METHODS``.
    sensor : the depth sensor, for the shadows of ``auto`` (``rgbd2scene.capture.sensors``).
    fx : focal length in px for the shadow widths; default 525 px * width / 640.
    border_width : widest border band in px; default 10 % of the shorter image side (48 px at 640x480).
    fill_border : False leaves the border band NaN.
    min_radius : a hole is beyond the sensor's range only if a disk of this radius (px) fits in it;
        default 5 % of the shorter image side.
    step : relative depth difference across a hole that counts as a depth step.
    small_radius : ``auto`` averages the colour-guided fill in where a hole bridges a depth step or its
        inscribed disk is wider than this radius (px); default 2.5 % of the shorter side.
    copies : ``auto`` chooses each hole's smooth fill on up to this many copies of it laid onto valid depth.
    inpaint_radius, inpaint_algorithm : ``cv2.inpaint`` radius (px) and ``"ns"`` or ``"telea"``.

    Returns
    -------
    FillResult

    Raises
    ------
    ValueError
        for an unknown method, a depth that is not a 2-D float array, an RGB image of another size.
    """
    t0 = time.perf_counter()
    if method not in FILL_METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(FILL_METHODS)}")
    depth = as_depth(depth)
    if inpaint_algorithm not in ("ns", "telea"):
        raise ValueError(f"inpaint algorithm must be 'ns' or 'telea', got {inpaint_algorithm!r}")
    h, w = depth.shape
    border_width = int(round(0.1 * min(h, w))) if border_width is None else max(int(border_width), 0)
    min_radius = 0.05 * min(h, w) if min_radius is None else float(min_radius)
    small_radius = 0.025 * min(h, w) if small_radius is None else float(small_radius)
    fx = KINECT_FX_640 * w / 640.0 if fx is None else float(fx)
    grey_levels(rgb, depth.shape)  # checks the RGB size
    valid = valid_depth(depth)
    work = np.where(valid, depth, np.nan).astype(np.float32)

    t1 = time.perf_counter()
    holes = classify_holes(work, border_width=border_width, min_radius=min_radius)
    classify_s = time.perf_counter() - t1
    todo = holes.fill if fill_border else holes.fill & ~holes.band
    band = holes.band & todo
    interior = todo & ~band

    used = method
    counts: dict[str, int] = {}
    if method == "none" or not valid.any() or not interior.any():
        out = work.copy()
    elif method == "inpaint":
        out = fill_inpaint(work, interior, radius=inpaint_radius, algorithm=inpaint_algorithm)
    elif method == "colorization":
        out = fill_colorization(work, rgb, interior)
    elif method == "nyu_colorization":
        out = fill_nyu_colorization(work, rgb, interior)
    elif method == "biharmonic":
        out = fill_biharmonic(work, interior)
    elif method == "background":
        out = fill_background(work, interior, step=step)
    else:
        out, counts = _auto(work, rgb, todo, band, step, fx, sensor.shadow_baselines(), small_radius, copies)
        used = "auto: " + ("+".join(counts) if counts else "nothing to fill")
    # the sensor's band, and holes only the band separates from the surface: the filled surface extended
    rest = todo & np.isnan(out) if method != "none" and band.any() else None
    if rest is not None and rest.any():
        out[rest] = fill_biharmonic(out, rest)[rest]
    out[valid] = depth[valid]  # valid pixels are never changed
    filled = holes.holes & np.isfinite(out)

    settings = {
        "method": method, "sensor": sensor.to_dict(), "fx": fx, "border_width": border_width,
        "fill_border": bool(fill_border), "min_radius": min_radius, "step": float(step),
        "small_radius": float(small_radius), "copies": int(copies), "inpaint_radius": float(inpaint_radius),
        "inpaint_algorithm": inpaint_algorithm, "space": "inverse depth", "rgb": rgb is not None,
    }
    stats = {
        "hole_fraction": float(holes.holes.mean()),
        "filled_fraction": float(filled.mean()),
        "left_unfilled_fraction": float((holes.holes & ~filled).mean()),
        "n_holes": components(todo)[1],
        **holes.stats(),
        "auto_pixels": counts,
        "classify_seconds": round(classify_s, 4),
        "seconds": round(time.perf_counter() - t0, 4),
    }
    return FillResult(out.astype(np.float32), filled, used, settings, stats)


def _auto(work, rgb, todo, band, step, fx, baselines, small_radius, copies):
    """``auto`` (module docstring): shadow rows (the band's too) -> their far end; holes with a depth
    step or wider than ``small_radius``, highlights excepted -> the mean of the colorization and
    biharmonic fills (biharmonic alone without RGB; clipped to the rim's depth range across a step);
    narrow step-free holes and highlights -> the smooth fill that did best on copies of them laid onto
    valid depth nearby. The rest of the band is left to the caller.

    Returns the filled depth and the number of pixels each method filled.
    """
    out = work.copy()
    counts: dict[str, int] = {}
    runs = step_runs(work, todo, step)
    shadow = shadow_pixels(runs, work, fx, baselines) & todo
    if shadow.any():
        out[shadow] = fill_row_background(work, shadow)[shadow]
        counts["background"] = int(shadow.sum())
    interior = todo & ~band
    rest = interior & ~shadow
    labels, n = components(interior)
    stepped = np.zeros(n + 1, dtype=bool)
    stepped[labels[runs.pixels(work.shape)]] = True
    stepped[0] = False
    wide = stepped.copy()
    inscribed = cv2.distanceTransform(interior.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    wide[labels[inscribed > small_radius]] = True
    if rgb is not None:  # a highlight's colour says nothing of its depth: the smooth fill, as for narrow holes
        shine = highlight_pixels(rgb, ~valid_depth(work))
        pixels = np.bincount(labels.ravel(), minlength=n + 1)
        wide &= 2 * np.bincount(labels.ravel(), weights=shine.ravel(), minlength=n + 1) < pixels
    guided = wide[labels] & rest
    small = rest & ~guided
    if guided.any():
        fill = fill_biharmonic(out, guided)
        across = guided & stepped[labels]  # a thin plate overshoots across a step, not on a smooth dome
        if across.any():
            fill = clip_to_rim(fill, out, across)
        if rgb is not None:  # their mean: neither wins on every hole, and their errors partly cancel
            guide = fill_colorization(out, rgb, guided)
            both = guided & np.isfinite(guide) & np.isfinite(fill)
            fill[both] = 0.5 * (fill[both] + guide[both])
            counts["colorization"] = int(both.sum())
        out[guided] = fill[guided]
        counts["biharmonic"] = int(guided.sum())
    if small.any():
        valid = valid_depth(work)
        name = choose_smooth_fill(out, small, valid & ~ndi.binary_dilation(~valid, iterations=2), copies)
        out[small] = SMOOTH_FILLS[name](out, small)[small]
        counts[name] = counts.get(name, 0) + int(small.sum())
    return out, counts


#: The smooth fills ``auto`` chooses between for narrow holes: most robust to noise (the choice where
#: no copy can be laid), or exact on planes.
SMOOTH_FILLS = {"harmonic": fill_harmonic, "biharmonic": fill_biharmonic}


def choose_smooth_fill(depth: np.ndarray, holes: np.ndarray, free: np.ndarray, copies: int = 3) -> str:
    """Which of :data:`SMOOTH_FILLS` had the least mean absolute depth error on copies of the holes laid
    onto valid depth nearby (:func:`~rgbd2scene.reconstruct.fill.holes.hole_copies`); the first where no
    copy fits.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    holes : bool (H, W) the holes whose shapes are copied (each 8-connected component is one hole).
    free : bool (H, W) valid pixels the copies may hide.
    copies : copies per hole.

    Returns
    -------
    str: a key of :data:`SMOOTH_FILLS`.
    """
    labels, _ = components(holes)
    source = hole_copies(labels, free, copies)
    test = source >= 0
    if not test.any():
        return next(iter(SMOOTH_FILLS))
    trial = np.where(test, np.nan, depth).astype(np.float32)
    truth = depth[test].astype(np.float64)
    miss = np.abs(truth - float(np.nanmedian(depth)))  # the error of a copy pixel left unfilled
    errors = {}
    for name, fill in SMOOTH_FILLS.items():
        e = np.abs(fill(trial, test)[test] - truth)
        errors[name] = float(np.where(np.isfinite(e), e, miss).mean())
    return min(errors, key=errors.get)
