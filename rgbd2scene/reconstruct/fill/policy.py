"""The hole-filling policy: :func:`fill_depth` decides which pixels to fill and, for ``auto``, how.

Methods (``FILL_METHODS``)
--------------------------
``inpaint``, ``colorization``, ``nyu_colorization``, ``biharmonic``, ``background``: one solver of
:mod:`rgbd2scene.reconstruct.fill.solvers` for every interior hole; ``auto`` (the default) chooses per hole
(below); ``none`` fills nothing. Whatever the method, the same pixels are filled
(:func:`~rgbd2scene.reconstruct.fill.holes.classify_holes`): every hole pixel on the captured surface; pixels
outside it stay NaN. Interior holes are filled by the method, then the sensor's border band (and any hole
that only the band separates from the surface) by a biharmonic fill from the surface and the filled
interior, bounded near the surface's depth range (4.; ``fill_border=False`` leaves the band NaN).

What ``auto`` does
------------------
Every rule decides from the capture itself. The figures are the benchmark's
(``benchmarks/bench_fill.py``: auto's all-pixel error over the best of the biharmonic, harmonic, NYU
colorization and the project's colorization fills, geometric mean over the rows); what was tried and not
kept, with its figures, is in ``benchmarks/results/fill.md`` (its notes, and the design record that this
docstring held until session 10). Until session 12 the tuning and held-out splits held the TUM frame and the
tissue sample only (77 rows each); from session 13 on they hold every capture (260 and 244 rows), and figures
before then are on the narrower splits.

1. **Occlusion shadows** (:func:`~rgbd2scene.reconstruct.fill.holes.shadow_pixels`): a horizontal run of
   hole pixels across a depth step, no wider than the shadow the sensor casts there, fx * b * (1/z_near -
   1/z_far) + 1 px, on the side the sensor casts it (``Sensor.shadow_baselines``), takes the depth of its
   far end (:func:`~rgbd2scene.reconstruct.fill.solvers.fill_row_background`): the shadow lies on the far
   surface. Only as far as the shadow reaches (:func:`~rgbd2scene.reconstruct.fill.holes.shadow_split`): a
   pixel beyond it whose colour is nearer the near end's is a dropout on the near surface's rim and takes
   the near end's depth. Nor where the near surface runs on under the run: its pixels from the near end on
   whose nearest valid pixels above and below lie on the near surface, in that surface's colour, at least 3
   of them in a row (fewer beside a row with 3), are a hole lying across the step (a dropout, a hole mask laid
   on another capture) rather than a shadow, whose near end is the near surface's outline itself, and take
   the near end's depth (session 14, ``fill.md``: tuning split 0.6434 -> 0.6396, rows above 1.10 47 -> 45;
   held-out 0.635 -> 0.632, 42 -> 41; the simulated shadow rows unchanged but one, by 0.1 %). A run holding
   a highlight brighter than both its ends (:func:`~rgbd2scene.reconstruct.fill.holes.highlight_runs`) is no
   shadow (the colour camera sees the far surface in a shadow, not the light) and is filled as a hole.
   Without RGB nothing confirms a run: it is a shadow only in a shadow's shape
   (:func:`~rgbd2scene.reconstruct.fill.holes.shadow_shaped`), its hole at least ``SHADOW_HOLE_SHARE`` shadow
   runs or its stack of shadow runs at least ``SHADOW_STACK`` times as tall as its widest run; the narrow rows
   at the round tip of a wider hole across a step are no shadow (taken as one, they held the far depth and
   pulled the hole's thin plate off the near surface: the NYU frame's tuning blobs row 6, 1.108 -> 0.997
   times the best reference; session 14, helper ``norgb14``, ``fill.md``). Time-of-flight sensors and
   ``sensor="none"`` cast no shadows. On the benchmark's simulated shadows the row fill is about 14 times as
   accurate as the best reference (family geometric mean 0.07).
2. **Holes with a depth step and holes wider than ``small_radius``** (an inscribed disk of radius above
   2.5 % of the shorter side), highlights excepted ("guided" holes): the mean of the NYU toolbox's
   colorization (:func:`~rgbd2scene.reconstruct.fill.solvers.fill_nyu_colorization`, on the known pixels
   within :data:`NYU_REACH` px of the holes) and the colour-guided thin plate
   (:func:`~rgbd2scene.reconstruct.fill.solvers.fill_guided_thin_plate`). The thin plate continues a
   surface's slope into the hole, exact on planes, but its couplings fall away where the colour changes, so
   it does not carry one surface's slope across an object's outline as the plain biharmonic fill does; the
   colorization follows the colour too but levels slopes off. The guided thin plate is clipped to each
   hole's rim depth range (:func:`~rgbd2scene.reconstruct.fill.solvers.clip_to_rim`): a part of a hole that
   colour edges cut loose from its rim is a plate with free edges and can overshoot. Where the colour leaves the
   guided thin plate on the plain one (:func:`agreeing_holes`: their mean difference over the hole under
   :data:`AGREE` of the guided thin plate's from NYU's fill), it shows nothing of the hole's shape, and NYU's fill,
   levelling the slope both thin plates continue, only pulls the mean off: the hole takes the plain thin plate
   (session 16, helper ``blob16``: Redwood's flat-coloured discs on sloped walls, a 2166 px one 80.9 mm in the mean,
   42.0 in the thin plate; tuning split 0.6245 -> 0.6225, rows above 1.10
   24 -> 24, no row up by more than 0.2 %; held-out 0.6209 -> 0.6197, 32 -> 31). **Planes** then
   replace that fill where the capture shows a plane
   (:func:`~rgbd2scene.reconstruct.fill.planes.planar_fill`): the colour image round the guided holes is
   cut into segments (Felzenszwalb, at 1 / :data:`PLANE_SCALE` resolution), each segment a hole cuts gets
   a robust plane in inverse depth from its valid pixels within 40 px, and its hole pixels take the plane
   where the residual is within twice the capture's own noise, the pixel within the support's spread, the
   plane within its depth range and the segment's valid pixel nearest the hole pixel on the plane (within
   three robust sigmas of the segment's residual: where a hole hides most of a surface the segmentation
   merged into a wall's segment, the wall's plane went in on that surface; session 13, ``fill.md``: tuning
   split 0.6639 -> 0.6593, rows above 1.10 58 -> 54 of 260; held-out 0.6560 -> 0.6530, 55 -> 52); within
   :data:`PLANE_RAMP` px of the rim the plane is blended in from the fill above, which is close to its data
   there. Walls, floors and desk tops pass; the tissue sample's
   curved surface mostly does not. **Quadrics** then replace that fill (planes included) where a hole's own ring
   shows one (:func:`~rgbd2scene.reconstruct.fill.planes.quadric_fill`): per guided hole, a robust quadric in
   inverse depth fitted to the valid pixels within :data:`~rgbd2scene.reconstruct.fill.planes.QUADRIC_REACH` (10) px
   of it, taken on the planes' tests (residual within twice the noise, the pixel within the ring's spread, the
   quadric within its depth range), blended in over the same ramp, from the edge of the pixels it takes (its apex
   beyond the ring's range keeps the fill below: the seam ramps too). A curved surface seen closely is a quadric to
   second order; a colour segment is not needed (on the tissue sample texture edges are not depth edges). It serves
   the smaller guided holes of smooth curved surfaces (the tissue sample's blobs: tuning rows up to 0.15 better) and
   of the TUM frame's; over a large hole nothing of low order fits: on the tissue sample's large holes even the
   quadric fitted to the hidden truth itself is worse than the best plain fill on 15 of 16 rows, so the ring test
   refuses them (residual 4.5-11 times the noise on their rings) and their misses stay (``fill.md``, session 12).
   Session 12: tuning split 0.677 -> 0.670, rows above 1.10 5 -> 5; held-out 0.705 -> 0.700, 6 -> 6. Without RGB:
   the biharmonic fill, clipped to the rim's range where the hole bridges a step (where the hole opens onto the border
   band filled in the same thin plate, the band's fill is part of that rim: :func:`_solved_rim`); where that clip pins
   more than :data:`PINNED_SHARE` of a hole wider than ``small_radius`` to its rim's nearest or farthest depth, the
   thin plate has carried the rim's slopes out of its range (the slopes do not continue across the hole), and the hole
   takes the mean of it and the harmonic fill, which levels off within the range (session 13: the NYU frame under a
   tuning ellipse over the chairs, 72 % pinned: 2.16 -> 1.17 times the best reference). Session 10 (planes and the thin
   plate together, against session 9's per-hole choice among the mean of the NYU colorization and the biharmonic
   fill, each alone, by copies of the hole laid on valid depth, whose evidence proved no better than always taking
   the mean): tuning split 0.753 -> 0.680, rows above 1.10 14 -> 5 of 77; held-out split 0.783 -> 0.706, 18 -> 9;
   report split 0.705 -> 0.673, 18 -> 17 of 101. A highlight (a hole at least half of whose pixels are bright,
   unsaturated and brighter than the surface round it: :func:`~rgbd2scene.reconstruct.fill.holes.highlight_pixels`)
   is not guided by colour, whatever its width: its colour is the light's, not the surface's (3.). Nor is a light
   inside a guided hole (:func:`~rgbd2scene.reconstruct.fill.holes.lights_in_holes`, session 14, helper ``spec14``): a
   blob of highlight pixels less than :data:`~rgbd2scene.reconstruct.fill.holes.LIGHT_SURROUND` of whose valid
   surround within 3 px is bright takes the hole's biharmonic fill (clipped as above) instead of the mean, planes
   and quadrics still taking over where they pass (SUN's ceiling lamp merged with the beyond-range region's margin:
   24-48 mm of the row's error in the mean, 10-21 in the thin plate; Redwood: a 2000 px highlight inside an
   18000 px hole, 15-48 mm against 3-8). Within an overexposed region the pixels that pass the highlight test
   are patches among clipped ones, their surround bright: they stay guided (there the mean beats the thin plate
   as often as not). Tuning split 0.6393 -> 0.6337, rows above 1.10 44 -> 35; with step 3's session 14 change,
   held-out 0.635 -> 0.627, 42 -> 33 (``fill.md``). **Noise-free
   depth** (session 13, :func:`plain_holes`): where a quadric fits each 7x7 window of the capture to float rounding
   (:func:`~rgbd2scene.reconstruct.fill.planes.noise_free`: depth from CT, a renderer; a plane's residual would count
   a smooth surface's curvature as noise), a wide hole enclosed by valid depth whose ring no depth edge crosses (no
   two neighbouring valid pixels within :data:`EDGE_REACH` px of it a step apart) takes the biharmonic fill alone,
   as without RGB: on a smooth surface measured exactly the thin plate continues the exact rim to second order,
   and colour adds only its texture (the tissue sample's organ from CT, ``tissue-ct``: there the mean of the
   colour-guided fills had up to 1.6 times the biharmonic fill's error on the large holes). A hole open to the region
   left unfilled (a notch in an organ's outline) keeps the mean (the thin plate extrapolates over the free edge),
   and so does a hole whose ring a depth edge crosses (the colour may show where the surface breaks inside it).
   Such a guided hole on noise-free depth no wider than :data:`EXACT_REACH` takes the colour-guided thin plate
   alone, not the mean with the NYU colorization (:func:`exact_holes`, session 17, helper ``hole17``): NYU's weighted
   averages level the exact rim's slopes and curvature off, which the guided thin plate continues while its colour
   edges still cut it where the surface breaks (tissue-ct's rows, the only noise-free capture: tuning 0.979 -> 0.973
   of the best reference, rows above 1.10 3 -> 1; held-out 0.993 -> 0.946, 3 -> 2; on the other captures the guided
   thin plate alone did worse than the mean). A wider hole keeps the mean: over the tuning split's large holes
   (63-81 px wide) the two fills' errors swap places (one row 1.08 -> 0.54, another 0.94 -> 1.23).
   Planes and quadrics are still fitted round every wide hole (the noise they are tested against is measured on
   the crop round them) but taken only in the colour-guided ones. Tuning split 0.6639 -> 0.6600 (rows above 1.10
   58 -> 53 of 260), held-out 0.6560 -> 0.6490 (55 -> 49 of 244), every row but tissue-ct's bit-identical
   (``fill.md``, session 13, helper ``ct13``).
3. **Narrow holes without a step, and highlights**: a harmonic or a biharmonic fill, whichever had the
   smaller error on copies of the holes (whole copies lying :data:`COPY_CLEARANCE` px from any invalid pixel;
   where no hole has one, copies lying 60 % on pixels 2 px from any invalid one). Harmonic averages a
   sensor's noise; biharmonic is exact on smooth noise-free depth (CT, a renderer), so the depth decides
   rather than the sensor setting. The narrow holes take one fill, the one all copies favour pooled
   (harmonic where none fits at all): their error is the noise's, the sensor's, the same across the image
   (session 9: per hole did worse on the TUM frame and the tissue sample). A wide highlight (wider than
   ``small_radius`` or across a step) takes the fill its own copies favour, and the biharmonic fill where it
   has no copy, as a wide hole neither lit nor colour-guided: over a wide hole whether a membrane or a thin
   plate fits is its surface's, and pooled, other holes' copies decided it (session 14, ``fill.md``, helper
   ``spec14``: SUN's two ceiling lamps, one lamp's copies erring 0.39-0.49 m (several times its own error) outweighing
   the other's 0.08-0.09 m, which favour the membrane that wins on both; Redwood's sunlit patch, 13766 px
   without a copy, 30.1 mm harmonic as its small holes' copies chose, 23.4 mm biharmonic; tuning split 0.6434 ->
   0.6393, rows above 1.10 47 -> 44, only specular rows moved). Only where its copies decide it: one fill's error on
   them less than half the other's (noise-free depth, where the thin plate's is near zero); else it takes the mean
   of both: on the real captures' highlights the two errors lie 1.0-2.4 times apart, and the ranking picked the
   worse fill for 15 of the 27 distinct tuning highlights with copies, the mean beating the pick on 18 (TUM's 127 px
   highlight: thin plate 4.2 mm of the row, membrane 2.2, mean 2.3; session 15, helper ``blob15``, ``fill.md``).
   Under white noise both fill from the smoothed rim (5.).
4. **The border band** (shadows in it excepted), per stretch of :data:`BAND_STRETCH` px along its edge
   (:func:`choose_band`): the strip of valid depth just inside each stretch (:func:`band_strips`) is hidden,
   band and strips are filled from the rest with the biharmonic, harmonic and NYU colorization fills (at 1 /
   :data:`BAND_SCALE` resolution), and each stretch takes the candidate of :data:`BAND_CANDIDATES` with the
   least mean absolute error on its strip, in inverse depth; the thin plate on a tie or where the strip is
   empty. In inverse depth, the space the fills are solved in: in metres an error of the same size in inverse
   depth grows with the square of the depth, so a strip's few far pixels decided for the whole stretch
   (session 11, ``fill.md``: tuning split 0.680 -> 0.677, held-out 0.706 -> 0.706 and rows above 1.10 9 -> 6).
   The membrane (harmonic fill) only where its strip error is below the other candidates' by
   :data:`BAND_MEMBRANE_MARGIN` (session 15, helper ``band15``): a strip's error favoured it narrowly where the
   band's own pixels take the thin plate (the NYU frame, no RGB, under transplanted bands 32 px wide: tuning NYU
   transplant 5 band 373 mm against the biharmonic fill's 307, with the margin 309). A stretch most of whose strip
   runs hold one surface but a depth step within the run's length beyond the strip (:func:`stepped_strips`) takes
   the thin plate (:data:`BAND_STEPPED_SHARE`; session 18, helper ``band18``): its trial filled the strip from a
   sliver of surface beside the step, the band is filled from the whole strip (the Redwood frame 3 under a 32 px
   band, a pillar 32-34 px further in: the trial's thin plate ran off the 2 px of wall beside it and the strips
   chose NYU's colorization; tuning Redwood3 transplant 5 band 32.9 mm of the row against the thin plate's 23.8,
   the same with the rule; tuning 0.6206 -> 0.6199, rows above 1.10 21 -> 20, no row worse). A step in the strip
   itself is left to the trial: it may run on into the band, where the colour follows it (marking those too
   cost tuning TUM blobs 6 0.64 -> 0.92).
   A band is an extrapolation: which continuation fits (a thin plate carrying the rim's slope on, a membrane
   levelling off where the rim is noisy, the colour where the band holds another surface) is what the surface
   just inside it shows. The thin plate is solved jointly with the holes that take a thin plate (a wide band
   beside a wide hole is one surface to continue); the band's harmonic and NYU fills only on the stretches
   that take them and beside them. The band's shadow fills (a shadow run's far depth) are no data for these
   solves (session 17): a band pixel between such a fill and the near surface took a ramp across both (SUN's
   lamp in the top band beside a shadow: tuning SUN specular 6 band 17.3 mm against the plain thin plate's 5.9,
   10.4 without; tuning 10 rows better, none worse; held-out 5 better, none worse). Whatever the fill, each band
   pixel is then clipped to the depth range of the valid pixels within the band's width of it, widened by
   :data:`BAND_MARGIN`
   (:func:`~rgbd2scene.reconstruct.fill.solvers.clip_to_surround`): where the surface recedes towards the edge
   a thin plate carries inverse depth on towards zero. Under white noise the band's thin plate and membrane
   fill from the smoothed rim (5.).
5. **The rim under white noise** (session 12): every fill takes the valid pixels as exact, and a thin plate
   carries each rim pixel's noise into the hole as a slope. Where the capture's noise is white (each pixel's
   own: :func:`~rgbd2scene.reconstruct.fill.planes.noise_correlation` of neighbouring pixels' residuals below
   :data:`WHITE_NOISE`) and above the floor (:data:`~rgbd2scene.reconstruct.fill.planes.NOISE_FLOOR`), the
   :data:`SMOOTH` fills (step 3's holes and the band's thin plate and membrane) fill from the rim smoothed
   (:func:`~rgbd2scene.reconstruct.fill.solvers.smooth_rim`: each valid pixel within 6 px of a hole or the band
   takes a local quadratic fit of inverse depth, Gaussian of 3 px, where that fit's residual is within 3 times
   the noise, so a depth step stays as measured); the output keeps the measured depth. Where neighbouring
   pixels share their deviations (a Kinect's disparity quantised in plateaus, fine relief: every real capture
   of the benchmark, 0.56-0.79) a hole's pixels share them with its rim too, and the measured rim is the better
   data (smoothed on the TUM frame too, with a 4 px Gaussian: tuning split 0.677 -> 0.687, rows above 1.10
   5 -> 8, its specular rows up by 0.10-0.24); noise-free depth (CT, a renderer) is not smoothed either (its
   residual is the curvature's, correlated). Not for the guided holes' colour-guided fills (2.; without RGB
   their biharmonic fill is one of the smooth fills): the wide holes' error is the fill's
   model, not the rim's noise (tissue sample, wide ellipses: filled from the true rim their error is no
   smaller), and smoothing their rim moved those rows by chance, more up than down. Of the benchmark's captures
   only the tissue sample's rim is smoothed: tuning split 0.6773 -> 0.6672 (rows above 1.10 5 -> 5), held-out
   0.7053 -> 0.6929 (6 -> 5); ``fill.md`` session 12.

Time: all of ``auto``'s solves share one pool of a thread per core, the longest (the thin plate of holes
and band, the guided holes' fills) started before the evidence is in, the band's other fills as soon as its
own evidence is in (not after the holes'); the symmetric positive definite systems (the thin plates, the
membrane) are factorised by CHOLMOD's supernodal Cholesky (:mod:`~rgbd2scene.reconstruct.fill.cholmod`), the
NYU colorization's unknowns (not symmetric) by SuperLU. On the TUM frame's own holes (640x480, 2 cores), session
21: 0.60 s wall warm, 0.71 s in a fresh process, 1.09-1.27 s CPU (session 20's LU: 0.83 s, 0.98 s, 1.51-1.82 s;
``benchmarks/results/fill.md``). The white-noise test (5.) costs about 0.01 s CPU; the smoothed
rim, where it is made, about 0.15-0.2 s more (the tissue sample's own holes), made while the guided holes'
fills run.

``FillResult.method`` names the base fills used, e.g. ``"auto: background+nyu_colorization+guided_thin_plate"``
(``FillResult.stats["auto_pixels"]``: how many pixels each filled; a pixel filled by the mean of two counts
for both; ``planes``, ``quadrics``: the guided holes' pixels that took their segment's plane or their hole's
quadric, which count for their other fill too).
"""

from __future__ import annotations

import os
import time
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage as ndi

from rgbd2scene.blas import single_blas_thread
from rgbd2scene.capture.sensors import KINECT_V1, Sensor
from rgbd2scene.reconstruct.fill.holes import (
    STEP,
    classify_holes,
    components,
    highlight_pixels,
    hole_copies,
    lights_in_holes,
    shadow_runs,
    shadow_shaped,
    shadow_split,
    step_runs,
    valid_depth,
)
from rgbd2scene.reconstruct.fill.planes import (
    NOISE_FLOOR,
    noise_correlation,
    noise_free,
    planar_fill,
    quadric_fill,
    sensor_noise,
)
from rgbd2scene.reconstruct.fill.solvers import (
    as_depth,
    check_rgb_size,
    clip_to_rim,
    clip_to_surround,
    fill_background,
    fill_biharmonic,
    fill_colorization,
    fill_guided_thin_plate,
    fill_harmonic,
    fill_inpaint,
    fill_nyu_colorization,
    fill_row_background,
    rim_range,
    smooth_rim,
)

FILL_METHODS = ("auto", "inpaint", "colorization", "nyu_colorization", "biharmonic", "background", "none")

#: The border band's fill is clipped to the depth range of the surface within the band's width of it, widened by
#: this fraction (:func:`~rgbd2scene.reconstruct.fill.solvers.clip_to_surround`; module docstring, 4.).
BAND_MARGIN = 0.1

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
    parts : bool (H, W) masks of the pixels each step filled: ``"shadow"`` (``auto``'s occlusion shadow
        runs: the shadows filled from their far end, the rim dropouts beyond them from the near end),
        ``"holes"`` (the interior holes, by the method or ``auto``'s choice per hole) and ``"band"`` (the
        border band and the holes only it separates from the surface: by ``auto``'s choice per stretch of
        the band, in the thin plate of the holes beside it, or extended from the surface afterwards).
    """

    depth: np.ndarray
    filled: np.ndarray
    method: str
    settings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    parts: dict = field(default_factory=dict)


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
    step: float = STEP,
    small_radius: float | None = None,
    copies: int = 3,
    inpaint_radius: float = 5.0,
    inpaint_algorithm: str = "ns",
) -> FillResult:
    """Fill the holes of a depth map that lie on the captured surface (module docstring).

    Parameters
    ----------
    depth : float32 (H, W) metres, NaN = hole (non-positive values are holes too).
    rgb : uint8 (H, W, 3) registered colour image (colorization needs it; optional otherwise: it also tells
        a hole's pixels at a surface's outline from the open background, ``holes.surface_by_colour``).
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
    copies : ``auto`` chooses each hole's fill on up to this many copies of it laid onto valid depth.
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
    check_rgb_size(rgb, depth.shape)
    valid = valid_depth(depth)
    work = np.where(valid, depth, np.nan).astype(np.float32)
    # auto's highlights (a distance transform over the image) beside the classification of the holes and the shadows
    shine = _started(highlight_pixels, rgb, ~valid_depth(work)) if method == "auto" and rgb is not None else None

    t1 = time.perf_counter()
    holes = classify_holes(work, border_width=border_width, min_radius=min_radius, rgb=rgb)
    classify_s = time.perf_counter() - t1
    todo = holes.fill if fill_border else holes.fill & ~holes.band
    band = holes.band & todo
    interior = todo & ~band

    used = method
    counts: dict[str, int] = {}
    shadow = np.zeros(depth.shape, dtype=bool)
    shadow_record = {"cast": False, "reason": f"the fill method {method!r} does not model shadows" if method != "auto"
                     else "no hole to fill inside the border band"}
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
        out, counts, shadow, shadow_record = _auto(work, rgb, shine, todo, band, step, fx, sensor.shadow_baselines(),
                                    small_radius, copies, border_width)
        used = "auto: " + ("+".join(counts) if counts else "nothing to fill")
        shadow_record = shadow_record.to_dict()
    # the sensor's band, and holes only the band separates from the surface: the filled surface extended
    rest = todo & np.isnan(out) if method != "none" and band.any() else None
    if rest is not None and rest.any():
        out[rest] = fill_biharmonic(out, rest)[rest]
    else:
        rest = np.zeros(depth.shape, dtype=bool)
    extended = (band & ~shadow) | rest  # auto's joint solve may have filled the band already
    # a thin plate continued to the image edge overshoots where the surface recedes: bound it by the
    # depth range the surface has within the band's width, with room for a slope that continues
    out = clip_to_surround(out, work, extended, border_width, BAND_MARGIN)
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
        "shadows": shadow_record,
        "classify_seconds": round(classify_s, 4),
        "seconds": round(time.perf_counter() - t0, 4),
    }
    parts = {"shadow": shadow & filled, "holes": interior & ~shadow & ~rest & filled, "band": extended & filled}
    return FillResult(out.astype(np.float32), filled, used, settings, stats, parts)


def _started(fn, *args) -> Future:
    """``fn(*args)`` running on a thread of its own; its result (or its exception) comes from the future."""
    thread = ThreadPoolExecutor(max_workers=1)
    try:
        return thread.submit(fn, *args)
    finally:
        thread.shutdown(wait=False)  # the thread ends with the job


def _auto(work, rgb, shine, todo, band, step, fx, baselines, small_radius, copies, border_width):
    """``auto`` (module docstring): shadow rows (the band's too) -> their far end; every other interior
    hole -> the fill :func:`choose_per_hole` picks for it; the band -> per stretch the fill
    :func:`choose_band` picks (the thin plate where the holes' solve holds it). The rest of the band is
    left to the caller. ``shine``: the future of the invalid pixels' highlights
    (:func:`~rgbd2scene.reconstruct.fill.holes.highlight_pixels`), None without RGB.

    Returns the filled depth, the number of pixels each fill filled, the shadow pixels and what the capture said of
    its shadows (:class:`~rgbd2scene.reconstruct.fill.holes.ShadowEvidence`).
    """
    out = work.copy()
    counts: dict[str, int] = {}
    # whether the capture's depth is noise-free (a test of the valid depth alone, 7 ms on the TUM frame): on a thread
    # of its own beside the shadows, off the serial path before the first solve
    noiseless = _started(noise_free, work, valid_depth(work)) if rgb is not None else None
    runs = step_runs(work, todo, step)
    kept, width, shadow_record = shadow_runs(runs, work, fx, baselines, rgb=rgb)
    if rgb is None and kept.line.size:  # no colour to confirm a shadow: its shape must
        shaped = shadow_shaped(kept, todo)
        kept, width = kept.subset(shaped), width[shaped]
    shadow, rim = shadow_split(kept, width, work, rgb)
    shadow &= todo
    rim &= todo
    if shadow.any():
        # each part of a run has one valid end (the other is the other part): the far end for the
        # shadow, the near end for the rim beyond the shadow's reach
        out[shadow] = fill_row_background(work, shadow)[shadow]
        out[rim] = fill_row_background(work, rim)[rim]
        counts["background"] = int(shadow.sum() + rim.sum())
        shadow |= rim
    rest = todo & ~band & ~shadow
    if not rest.any():
        return out, counts, shadow, shadow_record
    # the band's shadow fills are no data for the solves: a band pixel between a shadow's far fill and the near
    # surface takes the near surface's extension, not a ramp across both (SUN's lamp beside a shadow in the top band)
    given = out.copy()
    given[shadow & band] = np.nan
    labels, n = components(rest)
    stepped = np.zeros(n + 1, dtype=bool)
    stepped[labels[runs.pixels(work.shape) & rest]] = True
    stepped[0] = False
    wide = stepped.copy()
    inscribed = cv2.distanceTransform(rest.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    broad = np.zeros(n + 1, dtype=bool)
    broad[labels[inscribed > small_radius]] = True
    wide |= broad
    lit = np.zeros(n + 1, dtype=bool)
    if shine is not None:
        pixels = np.bincount(labels.ravel(), minlength=n + 1)
        lit = 2 * np.bincount(labels.ravel(), weights=shine.result().ravel(), minlength=n + 1) >= pixels
        lit[0] = False
    edge = band & ~shadow
    across = stepped[labels] & rest
    exact = noiseless is not None and noiseless.result()
    plain = plain_holes(work, todo, labels, n, step, exact=exact) if rgb is not None else None
    alone = exact_holes(labels, inscribed, exact)
    traits = HoleTraits(stepped, wide, lit, plain)
    # the thin plate of holes and band and the guided holes' fills (NYU colorization, colour-guided thin plate) are
    # the longest solves, and their inputs are known before any evidence: they start first, beside the evidence's
    # solves, where the rule's own choice (before the evidence) takes them (a guided hole's mean and the band's
    # thin plate beside it; the thin plate for a wide hole without RGB or a plain one, and for the guided holes'
    # evidence, :func:`agreeing_holes`); a result is used only if the evidence keeps its fill
    coloured = guided_holes(traits, rgb)
    guided = coloured[1:].any()
    uncoloured = (wide & ~lit & ~coloured)[1:].any()
    ahead = {"biharmonic": (rest | edge, across)} if (wide & ~lit)[1:].any() and (edge.any() or uncoloured or guided) \
        else {}
    if guided:
        ahead.update({b: (rest, across) for b in CANDIDATES[GUIDED]})
    with single_blas_thread(), ThreadPoolExecutor(max_workers=_solver_threads()) as solves, \
            ThreadPoolExecutor(max_workers=1) as side:
        # the smoothed rim (step 5) is made while the solves that do not take it run
        early = _submit_fills(solves, given, rgb, {b: job for b, job in ahead.items() if b not in SMOOTH})
        smoothed = _smoothed_rim(work, given, rest | edge)
        early.update(_submit_fills(solves, given, rgb, {b: job for b, job in ahead.items() if b in SMOOTH}, smoothed))
        band_fills = (side.submit(_band_fills, solves, work, given, rgb, edge, band, border_width, smoothed)
                      if edge.any() else None)
        # planes and quadrics: fitted round every wide hole but the highlights (the noise they are tested against is
        # measured on the crop round them: round the guided ones alone it may be a depth edge's), taken in the
        # guided ones (submitted last, below)
        planar = (rest & (wide & ~lit)[labels]) if guided else None
        # a light inside a guided hole (a lamp merged with a wider hole): its colour is the light's, it takes the
        # hole's thin plate (found while the solves run: no solve started above needs it)
        guided_px = rest & coloured[labels] if guided else None
        lights = (lights_in_holes(shine.result(), guided_px, rgb, valid_depth(work)) if guided
                  else np.zeros(work.shape, dtype=bool))
        choice = choose_per_hole(out, rgb, labels, traits, copies, pool=solves, step=step)
        ways, ways_used, band_jobs = ((np.zeros(work.shape, dtype=int), [], {}) if band_fills is None
                                      else band_fills.result())
        per_pixel = choice[labels]
        chosen = np.unique(choice[1:][np.bincount(labels.ravel(), minlength=n + 1)[1:] > 0])
        needed = {b for k in chosen for b in CANDIDATES[NAMES[k]]}
        jobs = {name: (rest, across) for name in sorted(needed | ({"biharmonic"} if lights.any() else set()))}
        if guided:  # the guided holes' evidence (:func:`agreeing_holes`), and the band's thin plate beside them
            jobs["biharmonic"] = (rest, across)
        joint = "biharmonic" in jobs and edge.any()
        if joint:  # the band in the same thin plate as the holes, not extended afterwards from their fills
            jobs["biharmonic"] = (rest | edge, across)
        for name in list(early):  # the same masks (the thin plate's rest | edge is rest where there is no band)
            if name in jobs:
                del jobs[name]
            else:  # not chosen after all: unused (the pool waits for it at its end if it has started)
                early.pop(name).cancel()
        early.update(_submit_fills(solves, given, rgb, _costly_first(jobs), smoothed))
        # the planes and quadrics last: no evidence waits for them, so they fill the cores while the last solves run
        # instead of holding the evidence's solves back (TUM frame: the band's trial solves, and with them its own NYU
        # fill, started 0.15 s later behind them, which then ran alone at the end: fill 0.99 -> 0.94 s, chrt)
        plane_fill = None if planar is None else solves.submit(planar_fill, work, rgb, planar, seg_scale=PLANE_SCALE)
        curve_fill = None if planar is None else solves.submit(quadric_fill, work, planar)
        fills = {name: future.result() for name, future in {**early, **band_jobs}.items()}
    # without RGB, the stepped holes whose thin plate its clip pins to the rim's range: levelled by the membrane
    solved = rest | edge if joint else rest
    pinned = (_pinned(fills["biharmonic"], _solved_rim(out, fills["biharmonic"], solved, across), across, broad[labels])
              if rgb is None and across.any() else None)
    if joint:
        out[edge] = fills["biharmonic"][edge]
    for k in chosen:
        sel = rest & (per_pixel == k)
        out[sel] = np.mean([fills[b][sel] for b in CANDIDATES[NAMES[k]]], axis=0)
        for b in CANDIDATES[NAMES[k]]:
            counts[b] = counts.get(b, 0) + int(sel.sum())
    if guided:  # the thin plate in the lights and where the colour-guided thin plate agrees with the plain one
        agree = agreeing_holes(labels, guided_px, *(fills[b] for b in (*CANDIDATES[GUIDED], "biharmonic")))
        plate = lights | (guided_px & agree[labels])
        _instead_of_mean(out, counts, plate, fills, "biharmonic")
        # noise-free depth: the colour-guided thin plate alone
        _instead_of_mean(out, counts, guided_px & alone[labels] & ~plate, fills, "guided_thin_plate")
    if pinned is not None and pinned.any():
        membrane = fills["harmonic"] if "harmonic" in fills else _base_fill("harmonic", out, None, pinned, across)
        out[pinned] = (out[pinned] + membrane[pinned]) / 2
        counts["harmonic"] = counts.get("harmonic", 0) + int(pinned.sum())
    # colour segments whose valid depth shows a plane: the plane; then holes whose ring shows a quadric: the quadric
    for name, model in (("planes", plane_fill), ("quadrics", curve_fill)):
        if model is not None:
            taken = _blend_in(out, model.result(), planar & coloured[labels], seamless=name == "quadrics")
            if taken:
                counts[name] = taken
    for k in ways_used:  # the band's stretches that their strips gave another fill than the thin plate
        sel = ways == k
        parts = BAND_CANDIDATES[BAND_NAMES[k]]
        if "biharmonic" in parts:  # the joint thin plate, else one of the band alone
            fills["band:biharmonic"] = fills["biharmonic"] if joint else fill_biharmonic(out, sel)
        out[sel] = np.mean([fills["band:" + b][sel] for b in parts], axis=0)
        for b in parts:
            counts[b] = counts.get(b, 0) + int(sel.sum())
    return out, counts, shadow, shadow_record


#: Without RGB, a stepped hole whose thin plate lies on its rim's depth bound over more than this share of its pixels
#: takes the mean of it and the harmonic fill (module docstring, 2.).
PINNED_SHARE = 0.25


def _instead_of_mean(out: np.ndarray, counts: dict[str, int], where: np.ndarray, fills: dict[str, np.ndarray],
                     name: str) -> None:
    """``out`` takes the fill ``name`` on ``where``, pixels of colour-guided holes that had the mean of the guided fills
    (:data:`GUIDED`); ``counts`` (pixels per fill) moves them from the mean's fills to ``name``."""
    taken = int(where.sum())
    if not taken:
        return
    out[where] = fills[name][where]
    counts[name] = counts.get(name, 0) + taken
    for b in CANDIDATES[GUIDED]:
        counts[b] -= taken
        if not counts[b]:  # every guided hole took another fill
            del counts[b]


#: A colour-guided hole whose guided thin plate lies nearer the plain thin plate than this share of its distance from
#: NYU's colorization takes the plain thin plate (:func:`agreeing_holes`).
AGREE = 0.1


def agreeing_holes(labels: np.ndarray, where: np.ndarray, nyu: np.ndarray, plate: np.ndarray,
                   thin_plate: np.ndarray) -> np.ndarray:
    """Per hole label, whether the colour-guided hole's guided thin plate ``plate`` agrees with the plain thin plate
    ``thin_plate``: their mean absolute difference over the hole's pixels in ``where`` less than :data:`AGREE` times
    that of ``plate`` and NYU's colorization ``nyu``. Where colour does not steer the thin plate off the plain one,
    the colour shows nothing of the surface's shape there (flat, or its edges not the hole's), and NYU's fill, which
    levels slopes off, pulls the mean of the two guided fills off the slope both thin plates continue (module
    docstring, 2.; session 16, helper ``blob16``).

    Parameters
    ----------
    labels : int (H, W) the holes (0 = none).
    where : bool (H, W) the colour-guided holes' pixels (:func:`guided_holes`).
    nyu, plate, thin_plate : float (H, W) the fills there (NaN: no evidence).

    Returns
    -------
    bool (labels.max() + 1,): False for every hole without a pixel in ``where``.
    """
    n_labels = int(labels.max()) + 1
    at = np.flatnonzero(where)
    n, p, m = (f.ravel()[at].astype(np.float64) for f in (nyu, plate, thin_plate))
    apart, near = np.nan_to_num(np.abs(n - p)), np.nan_to_num(np.abs(p - m))  # an unfilled pixel: no evidence
    lab = labels.ravel()[at]
    agree = np.bincount(lab, near, n_labels) < AGREE * np.bincount(lab, apart, n_labels)
    agree[0] = False
    return agree


def exact_holes(labels: np.ndarray, inscribed: np.ndarray, exact: bool) -> np.ndarray:
    """Per hole label, whether a colour-guided hole there takes the colour-guided thin plate alone instead of the
    mean with the NYU colorization (module docstring, 2.): the capture's depth is noise-free (``exact``:
    :func:`~rgbd2scene.reconstruct.fill.planes.noise_free`), where NYU's weighted averages level the exact rim's
    slopes and curvature off, and the hole is no wider than :data:`EXACT_REACH` (no pixel farther from its rim).

    Parameters
    ----------
    labels : int (H, W) the holes (0 = none).
    inscribed : float (H, W) each hole pixel's distance from the nearest pixel outside the holes (px).
    exact : whether the capture's depth is noise-free.

    Returns
    -------
    bool (labels.max() + 1,): False for label 0, and for every hole where ``exact`` is False.
    """
    alone = np.full(int(labels.max()) + 1, exact, dtype=bool)
    if exact:  # else a sensor's capture (every benchmark frame but CT's): no hole takes it, no width to look at
        alone[labels[inscribed > EXACT_REACH]] = False
    alone[0] = False
    return alone


def _solved_rim(depth: np.ndarray, fill: np.ndarray, mask: np.ndarray, across: np.ndarray) -> np.ndarray:
    """``depth`` with the pixels of ``mask`` outside ``across`` taken from ``fill``: what a stepped hole's thin plate
    is bounded by (:func:`~rgbd2scene.reconstruct.fill.solvers.clip_to_rim`). Where a hole opens onto the border band
    filled in the same solve, the band's fill is its rim there as much as the valid depth is: a surface that shows
    only beyond the band (a near object at the image's edge) reaches the hole through it, and the valid rim's range
    alone would cut it off (the NYU frame's left edge)."""
    own = mask & ~across & np.isfinite(fill)
    return np.where(own, fill, depth) if own.any() else depth


def _pinned(fill: np.ndarray, depth: np.ndarray, across: np.ndarray, broad: np.ndarray) -> np.ndarray:
    """The pixels of the ``broad`` holes of ``across`` whose ``fill`` (clipped to the rim's range,
    :func:`~rgbd2scene.reconstruct.fill.solvers.clip_to_rim`, against ``depth``) lies on the rim's least or greatest
    depth over more than :data:`PINNED_SHARE` of their pixels."""
    labels, lo, hi = rim_range(depth, across)
    labels[~broad] = 0
    bound = across & ((fill <= lo[labels]) | (fill >= hi[labels]))
    pixels = np.bincount(labels.ravel(), minlength=lo.size)
    share = np.bincount(labels[bound], minlength=lo.size) / np.maximum(pixels, 1)
    share[0] = 0.0
    return across & (share[labels] > PINNED_SHARE)


def _blend_in(out: np.ndarray, model: np.ndarray, where: np.ndarray, seamless: bool = False) -> int:
    """``model``'s depth written into ``out`` on the pixels of ``where`` it holds, blended in linearly over the
    :data:`PLANE_RAMP` px next to the rim of ``where`` (there the fill in ``out`` is close to its data, the
    model deeper in), or with ``seamless`` next to the edge of the pixels it holds (where the model holds only
    part of a hole, the seam to the rest ramps too); returns how many pixels took it."""
    sel = where & np.isfinite(model)
    w = np.minimum(cv2.distanceTransform((sel if seamless else where).astype(np.uint8), cv2.DIST_L2, 3)[sel]
                   / PLANE_RAMP, 1.0)
    out[sel] = w * model[sel] + (1 - w) * out[sel]
    return int(sel.sum())


def _costly_first(jobs: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``jobs`` (:func:`_base_fills`) in the order to submit them: the costly NYU fills first, then the larger first,
    so that the last to start is a short one."""
    order = sorted(jobs, key=lambda name: (not name.endswith("nyu_colorization"), -int(jobs[name][0].sum())))
    return {name: jobs[name] for name in order}


def _band_fills(pool: Executor, work, out, rgb, edge, band, border_width, smoothed=None):
    """The border band's fill per stretch (:func:`choose_band`) and the fills it takes besides the thin plate,
    submitted to ``pool`` as soon as the choice is in, beside the holes' evidence rather than after it (the last
    of them otherwise ran alone at the end of the fill, one core idle).

    Returns the choice per pixel of ``edge`` (0: the thin plate, none of these fills), the indices of
    :data:`BAND_NAMES` it takes other than 0, and the futures of the fills, named ``"band:<fill>"``.
    """
    ways = choose_band(work, rgb, edge, band, border_width, pool)
    ways_used = [k for k in range(1, len(BAND_NAMES)) if (ways == k).any()]
    jobs = {}
    for b in sorted({b for k in ways_used for b in BAND_CANDIDATES[BAND_NAMES[k]]} - {"biharmonic"}):
        # only where taken, and the band beside it: half a stretch for the costly NYU fill, a whole one for the
        # membrane, whose free end at the cut reaches further (half a stretch: tuning rows up to 0.014 worse)
        taken = np.isin(ways, [k for k in ways_used if b in BAND_CANDIDATES[BAND_NAMES[k]]])
        beside = BAND_STRETCH if b == "harmonic" else BAND_STRETCH // 2
        where = edge & (cv2.distanceTransform((~taken).astype(np.uint8), cv2.DIST_C, 3) <= beside)
        jobs[f"band:{b}"] = (where, np.zeros(edge.shape, dtype=bool))
    return ways, ways_used, _submit_fills(pool, out, rgb, _costly_first(jobs), smoothed)


#: What ``auto`` chooses from per hole: one base fill, or the mean of two (:func:`choose_per_hole`).
CANDIDATES: dict[str, tuple[str, ...]] = {
    "harmonic": ("harmonic",),
    "biharmonic": ("biharmonic",),
    "nyu_colorization+guided_thin_plate": ("nyu_colorization", "guided_thin_plate"),
    "harmonic+biharmonic": ("harmonic", "biharmonic"),
}
NAMES = list(CANDIDATES)
#: The fill of a colour-guided hole (module docstring, 2.), then planes where the capture shows them: no choice by
#: copies (choosing among it, the biharmonic fill and the NYU colorization did worse, ``fill.md`` session 10).
GUIDED = "nyu_colorization+guided_thin_plate"
#: On noise-free depth a colour-guided hole no wider than this many px (its farthest pixel from the rim) takes the
#: guided thin plate alone (:func:`exact_holes`): the tuning split's guided holes there are up to 25 px wide, its
#: large holes 63-81 px, over which the thin plate's and NYU's errors swap places.
EXACT_REACH = 40.0
#: What narrow holes and highlights choose between on copies (module docstring, 3.).
SMOOTH = ("harmonic", "biharmonic")
#: Within this many px of a guided hole's rim its plane or quadric is blended in linearly from the hole's other fill
#: (step 2).
PLANE_RAMP = 8.0
#: The colour segmentation of step 2's planes runs at 1 / this resolution (at 1/2: about 0.04 s more CPU on the TUM
#: frame, tuning 0.732, 8 rows above 1.10, held-out 0.766, 15; at 1/3 0.731, 10 and 0.762, 15).
PLANE_SCALE = 3
#: A depth edge within this many px of a hole keeps its colour guidance on noise-free depth (:func:`plain_holes`; the
#: quadrics' ring).
EDGE_REACH = 10
#: ``auto``'s NYU colorization graph: the known pixels within this many px of the holes (its docstring).
NYU_REACH = 16
#: ``auto``'s NYU colorization: its solve stops once the filled depth is provably within this share of the largest
#: known depth of the exact solution (session 20 set it for GMRES's relative residual, where the fill moved by up to
#: 0.2 mm against 1e-7; the bound of session 21's solve holds at 0.1 mm on the TUM frame).
NYU_RTOL = 1e-5
#: Copies lie this many px away from any invalid pixel: a copy must be enclosed by valid depth, as the hole is.
COPY_CLEARANCE = 6
#: A wide highlight's own copies pick one smooth fill only where its error on them is less than 1 / this of the
#: other's (noise-free depth: the thin plate's is near zero); else it takes the mean of both (the real captures'
#: highlights: the errors 1.0-2.4 times apart, the pick the worse fill for 15 of 27, ``fill.md`` session 15).
COPY_DECISIVE = 2.0
#: The rim is smoothed for the :data:`SMOOTH` fills only where neighbouring pixels' noise correlates less than this
#: (:func:`~rgbd2scene.reconstruct.fill.planes.noise_correlation`: white noise about 0, the benchmark's real captures
#: 0.56 and more, the tissue sample's simulated noise 0.26; module docstring, 5.).
WHITE_NOISE = 0.4


def _smoothed_rim(work: np.ndarray, out: np.ndarray, mask: np.ndarray) -> np.ndarray | None:
    """``out`` with the rim of ``mask`` smoothed (:func:`~rgbd2scene.reconstruct.fill.solvers.smooth_rim`) where the
    capture ``work`` shows white noise above the floor; None (fill from the measured rim) elsewhere (module
    docstring, 5.)."""
    valid = valid_depth(work)
    if noise_correlation(work, valid) >= WHITE_NOISE:
        return None
    noise = sensor_noise(work, valid)
    return smooth_rim(out, mask, noise) if NOISE_FLOOR < noise < np.inf else None


@dataclass
class HoleTraits:
    """Per hole label (index 0: no hole): bridges a depth step; wider than ``small_radius`` or stepped;
    a specular highlight; filled without colour guidance on noise-free depth (:func:`plain_holes`; None: no hole
    is)."""

    stepped: np.ndarray
    wide: np.ndarray
    lit: np.ndarray
    plain: np.ndarray | None = None


def _base_fill(name: str, depth, rgb, mask, across) -> np.ndarray:
    """The base fill ``name`` of ``mask`` (one solve); the biharmonic one clipped to the rim's depth range on
    ``across`` (a thin plate overshoots across a depth step), the colour-guided thin plate on every hole."""
    if name == "harmonic":
        return fill_harmonic(depth, mask)
    if name == "biharmonic":
        f = fill_biharmonic(depth, mask)
        return clip_to_rim(f, _solved_rim(depth, f, mask, across), across) if across.any() else f
    if name == "guided_thin_plate":  # every hole clipped: a thin plate cut loose by colour edges may overshoot
        return clip_to_rim(fill_guided_thin_plate(depth, rgb, mask), depth, mask)
    return fill_nyu_colorization(depth, rgb, mask, rtol=NYU_RTOL, reach=NYU_REACH)


def _solver_threads() -> int:
    """Threads for ``auto``'s solves: one per core this process may use."""
    return max(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1, 1)


def _submit_fills(pool: Executor, depth, rgb, jobs: dict[str, tuple[np.ndarray, np.ndarray]],
                  smoothed: np.ndarray | None = None) -> dict[str, Future]:
    """Each named base fill of ``jobs`` (:func:`_base_fills`) submitted to ``pool``, in the order of ``jobs``;
    ``smoothed``: the depth the :data:`SMOOTH` fills take instead of ``depth`` (:func:`_smoothed_rim`)."""
    return {name: pool.submit(_base_fill, b, depth if smoothed is None or b not in SMOOTH else smoothed, rgb, *job)
            for name, job in jobs.items() for b in [name.removeprefix("band:")]}


def _base_fills(depth, rgb, jobs: dict[str, tuple[np.ndarray, np.ndarray]],
                pool: Executor | None = None) -> dict[str, np.ndarray]:
    """Each named base fill (:func:`_base_fill`; a name ``"band:<fill>"`` runs ``<fill>``: the band's own solve
    beside the holes') of its ``(mask, across)`` in ``jobs``, the solves side by side
    in threads, each on one BLAS thread (:mod:`rgbd2scene.blas`): the sparse solvers release the GIL, so on two
    cores they overlap (TUM frame: the fill 0.70 s wall instead of 1.0 s); each result is the same. ``pool``:
    the solves go to this pool (its caller holds :func:`~rgbd2scene.blas.single_blas_thread`), not to their own
    threads, so that ``auto``'s solves queue for the cores together, longest first."""
    if pool is None:
        with single_blas_thread(), ThreadPoolExecutor(max_workers=max(len(jobs), 1)) as own:
            return _base_fills(depth, rgb, jobs, own)
    return {name: future.result() for name, future in _submit_fills(pool, depth, rgb, jobs).items()}


def _copy_errors(depth, labels, traits: HoleTraits, clearance: int, coverage: float, copies: int,
                 pool: Executor | None = None, step: float = STEP):
    """Mean absolute error of each :data:`SMOOTH` fill on each hole's copies (inf where none fits) and the
    copies' pixel count per hole. A copy that bridges a depth step (:func:`~rgbd2scene.reconstruct.fill.holes.
    step_runs`, ``step``) where its hole does not is left out: a narrow hole across a step would be a guided one
    (module docstring, 3.), and such a copy's error is the step's, not the surface's."""
    n = traits.wide.size - 1
    valid = valid_depth(depth)
    free = valid & ~ndi.binary_dilation(~valid, iterations=clearance)
    source = hole_copies(labels, free, copies, coverage=coverage)
    test = source >= 0
    if test.any():
        pieces, _ = components(test)
        owners = np.zeros(pieces.max() + 1, dtype=int)
        owners[pieces[test]] = labels.ravel()[source[test]]
        bridged = np.zeros(owners.size, dtype=bool)
        bridged[pieces[step_runs(np.where(test, np.nan, depth), test, step).pixels(depth.shape) & test]] = True
        test &= ~(bridged & ~traits.stepped[owners])[pieces]
    err = np.full((n + 1, len(SMOOTH)), np.inf)
    if not test.any():
        return err, np.zeros(n + 1)
    owner = labels.ravel()[source[test]]
    trial = np.where(test, np.nan, depth).astype(np.float32)
    truth = depth[test].astype(np.float64)
    miss = np.abs(truth - float(np.nanmedian(depth)))  # the error of a copy pixel left unfilled
    across = np.zeros(labels.shape, dtype=bool)
    across[test] = traits.stepped[owner]
    fills = _base_fills(trial, None, {name: (test, across) for name in SMOOTH}, pool)
    npx = np.bincount(owner, minlength=n + 1).astype(np.float64)
    for k, name in enumerate(SMOOTH):
        est = fills[name][test]
        e = np.where(np.isfinite(est), np.abs(est - truth), miss)
        err[:, k] = np.bincount(owner, weights=e, minlength=n + 1) / np.maximum(npx, 1.0)
    return err, npx


def plain_holes(depth: np.ndarray, todo: np.ndarray, labels: np.ndarray, n: int, step: float,
                reach: int = EDGE_REACH, exact: bool | None = None) -> np.ndarray:
    """Per hole label (index 0: none), whether the hole is filled by the thin plate alone, its colour set aside
    (module docstring, 2.): the capture is noise-free (:func:`~rgbd2scene.reconstruct.fill.planes.noise_free`),
    the hole is enclosed by valid depth (it touches no invalid pixel outside ``todo``, the pixels to fill: a hole
    open to the region outside the surface has a free edge there, over which a thin plate extrapolates), and no
    depth edge crosses its ring (two 4-adjacent valid pixels, one within ``reach`` px of the hole and nearer it
    than any other hole, whose inverse depths differ by more than ``step``: where the surface breaks, the colour
    may show where it breaks inside the hole). ``exact``: whether the capture is noise-free, where the caller knows
    it (None: found here)."""
    valid = valid_depth(depth)
    plain = np.zeros(n + 1, dtype=bool)
    if not (noise_free(depth, valid) if exact is None else exact):
        return plain
    plain[1:] = True
    beyond = ndi.binary_dilation(~valid & ~todo, structure=np.ones((3, 3), dtype=bool))
    plain[labels[beyond]] = False
    inv = np.where(valid, 1.0 / np.where(valid, depth, 1.0), np.nan)
    edge = np.zeros(depth.shape, dtype=bool)
    for axis in (0, 1):  # both pixels of each jump between neighbours along this axis
        a, b = np.swapaxes(inv, 0, axis)[:-1], np.swapaxes(inv, 0, axis)[1:]
        with np.errstate(invalid="ignore"):
            jump = np.abs(a - b) > step * np.minimum(a, b)
        e = np.swapaxes(edge, 0, axis)
        e[:-1] |= jump
        e[1:] |= jump
    distance, (near_v, near_u) = ndi.distance_transform_edt(labels == 0, return_indices=True)
    plain[labels[near_v, near_u][edge & (distance <= reach)]] = False
    plain[0] = False
    return plain


def guided_holes(traits: HoleTraits, rgb: np.ndarray | None) -> np.ndarray:
    """Per hole label, whether it is colour-guided (module docstring, 2.): wide or across a step, not a
    highlight, with RGB, and not a plain hole of noise-free depth (:func:`plain_holes`)."""
    guided = traits.wide & ~traits.lit & (rgb is not None)
    if traits.plain is not None:
        guided &= ~traits.plain
    guided[0] = False
    return guided


def choose_per_hole(depth: np.ndarray, rgb: np.ndarray | None, labels: np.ndarray, traits: HoleTraits,
                    copies: int = 3, pool: Executor | None = None, step: float = STEP) -> np.ndarray:
    """Per hole, the index in :data:`NAMES` of its fill (module docstring, steps 2 and 3).

    Copies of each narrow hole and highlight are laid onto valid depth nearby, each wholly on pixels at least
    :data:`COPY_CLEARANCE` px from any invalid one (:func:`~rgbd2scene.reconstruct.fill.holes.hole_copies`),
    and filled with the candidates: all copies at once, one solve per base fill. The narrow holes take the
    smooth fill (harmonic or biharmonic) with the least error over all their copies pooled; where none of
    them has a whole copy, over copies that lie 60 % on pixels 2 px from any invalid one (a thin ring round a
    hole beyond range has no room for a whole copy); harmonic where none fits at all. A copy that bridges a depth
    step its hole does not is no evidence (:func:`_copy_errors`). A wide highlight takes
    the smooth fill with the least error over its own copies where that error is less than 1 /
    :data:`COPY_DECISIVE` of the other's, else the mean of both, and the biharmonic fill where it has no copy. A
    colour-guided hole (wide or across a step, not a highlight, with RGB) takes
    :data:`GUIDED` (the mean of the NYU colorization and the colour-guided thin plate); without RGB, the
    biharmonic fill.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    rgb : uint8 (H, W, 3) or None.
    labels : int (H, W) the holes (0 = none), one label per hole.
    traits : per label.
    copies : copies per hole.
    pool : where the solves run (:func:`_base_fills`); None: threads of their own.

    Returns
    -------
    int (n + 1,): an index of :data:`NAMES` per label (index 0 unused).
    """
    n = traits.wide.size - 1
    smooth = ~traits.wide | traits.lit
    smooth[0] = False
    guided = guided_holes(traits, rgb)
    choice = np.full(n + 1, NAMES.index("harmonic"))
    choice[guided] = NAMES.index(GUIDED)
    choice[1:][~smooth[1:] & ~guided[1:]] = NAMES.index("biharmonic")  # wide, neither lit nor colour-guided
    if not smooth.any():  # the copies only choose the smooth fill
        return choice
    smooth_only = np.where(smooth[labels], labels, 0)  # the other holes' copies would take room and solve time
    err, npx = _copy_errors(depth, smooth_only, traits, COPY_CLEARANCE, 1.0, copies, pool, step)
    if not (smooth & (npx > 0)).any():
        err, npx = _copy_errors(depth, smooth_only, traits, 2, 0.6, copies, pool, step)
    scored = smooth & (npx > 0)
    if scored.any():  # narrow holes: one smooth fill for all, which all copies favour pooled: noise is the sensor's
        best = int((err[scored] * npx[scored, None]).sum(axis=0).argmin())
        choice[smooth] = NAMES.index(SMOOTH[best])
    # a wide highlight: what its own copies favour (whether a membrane or a thin plate fits a wide hole is its
    # surface's, not the noise's: pooled, other holes' copies decide it), the thin plate where it has no copy, as a
    # wide hole neither lit nor colour-guided
    wide_lit = smooth & traits.wide
    own = np.array([NAMES.index(name) for name in SMOOTH])[err.argmin(axis=1)]
    with np.errstate(invalid="ignore"):  # no copy: inf / inf, not decisive (and not used below)
        decisive = err.max(axis=1) > COPY_DECISIVE * err.min(axis=1)
    # copies that rank the fills by less than that are the noise's and the copies' own surfaces': both fills
    own[~decisive] = NAMES.index("harmonic+biharmonic")
    choice[wide_lit & (npx > 0)] = own[wide_lit & (npx > 0)]
    choice[wide_lit & (npx == 0)] = NAMES.index("biharmonic")
    return choice


#: What the border band chooses from per stretch of an edge (:func:`choose_band`; the default, the thin plate, first).
BAND_CANDIDATES: dict[str, tuple[str, ...]] = {
    "biharmonic": ("biharmonic",),
    "harmonic": ("harmonic",),
    "nyu_colorization": ("nyu_colorization",),
    "nyu_colorization+biharmonic": ("nyu_colorization", "biharmonic"),
}
BAND_NAMES = list(BAND_CANDIDATES)
#: The border band chooses its fill per stretch of this many px along its edge (:func:`choose_band`).
BAND_STRETCH = 64
#: The band's evidence is solved at 1 / this resolution: at full resolution it chose about as well on the tuning split
#: (geometric mean 0.756 against 0.755, measured with the band's fills solved after the holes') and cost 1 s more; at
#: quarter resolution (session 10) 0.14 s CPU less on the TUM frame, but held-out 0.783 -> 0.786, tuning 0.753 -> 0.753.
BAND_SCALE = 2
#: A stretch takes the membrane (harmonic fill) only where its strip error is below the other candidates' by this
#: factor: a membrane levels off at the cut, and a strip's error favours it where the band's own pixels do not.
BAND_MEMBRANE_MARGIN = 1.2


def _edge_view(a: np.ndarray, transpose: bool, flip: bool) -> np.ndarray:
    a = a.T if transpose else a
    return a[:, ::-1] if flip else a


def band_strips(band: np.ndarray, valid: np.ndarray, stretch: int = BAND_STRETCH,
                scale: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The border band's stretches and, for each, the strip of valid depth just inside it.

    Along each edge, each row (left and right edges) or column (top and bottom) of the band is a run of
    band pixels from the edge; its strip is the same run shifted inward by its own length (the band's
    shape moved inward by its width), on the valid pixels there. Runs are grouped into stretches of
    ``stretch`` px along the edge; a corner pixel belongs to the first edge that claims it.

    Parameters
    ----------
    band : bool (H, W) the border band.
    valid : bool (H, W) valid depth.
    stretch : px along an edge, at full resolution.
    scale : the arrays are 1 / ``scale`` of the full resolution: the stretches are numbered as at full
        resolution (so that a strip found at half resolution names its band's stretch at full resolution;
        exact where the image's sides are multiples of ``scale``).

    Returns
    -------
    int (H, W) the stretch of each band pixel (0: none) and int (H, W) the stretch whose strip each
    valid pixel lies in (0: none).
    """
    seg_band = np.zeros(band.shape, dtype=np.int32)
    seg_strip = np.zeros(band.shape, dtype=np.int32)
    label = 0
    for flip in (False, True):
        for transpose in (False, True):
            # the edge at column 0 of each row; views, so that writes go through
            b, v, sb, ss = (_edge_view(a, transpose, flip) for a in (band, valid, seg_band, seg_strip))
            n, m = b.shape
            off = ~b
            run = np.where(off.any(axis=1), off.argmax(axis=1), m)
            # runs and strips lie within twice the longest run of the edge: the rest of the image is left out
            reach = min(m, 2 * int(run.max()))
            b, v, sb, ss = b[:, :reach], v[:, :reach], sb[:, :reach], ss[:, :reach]
            col = np.arange(reach)[None, :]
            cells = col < run[:, None]
            strip = (col >= run[:, None]) & (col < 2 * run[:, None]) & v & ~b & (ss == 0)
            ids = label + 1 + (np.arange(n) * scale) // stretch
            sb[cells & (sb == 0)] = np.broadcast_to(ids[:, None], cells.shape)[cells & (sb == 0)]
            ss[strip] = np.broadcast_to(ids[:, None], strip.shape)[strip]
            label += -(-(n * scale) // stretch)
    return seg_band, seg_strip


#: A stretch takes the thin plate where more than this share of its strip's pixels lie in runs with a depth step just
#: beyond the strip and none in it (:func:`stepped_strips`): its trial filled the strip from a sliver beside the step.
BAND_STEPPED_SHARE = 0.5


def stepped_strips(band: np.ndarray, depth: np.ndarray, step: float = STEP) -> np.ndarray:
    """The valid pixels of the border band's strips (:func:`band_strips`) whose run has a depth step just beyond
    the strip and none in it.

    :func:`choose_band` hides each strip run (the band's run along a row or column, moved inward by its own length)
    and fills it from the valid depth beyond, as the band is filled from its strip. Where the strip holds one
    surface but a step lies within the run's length beyond it, the trial fills the strip from a sliver of that
    surface beside the step, or from the surface across it, while the band is filled from the whole strip: the
    trial's error then says nothing of the band's fill (the Redwood frame 3 under a 32 px band, a pillar 32-34 px
    further in: the trial's thin plate ran off the 2 px of wall left beside it, 0.06 1/m in inverse depth against the
    colour's 0.009, where in the band it beat NYU's colorization by 2.3 times). A step in the strip itself may run on
    into the band, where the colour may follow it: such a run is left to the trial.

    Parameters
    ----------
    band : bool (H, W) the border band.
    depth : float (H, W) metres, NaN = invalid.
    step : relative difference in inverse depth between neighbouring valid pixels that makes a step.

    Returns
    -------
    bool (H, W): True on the strip pixels (as :func:`band_strips` assigns them to the edges) of such runs.
    """
    valid = valid_depth(depth)
    inv = np.where(valid, 1.0 / np.where(valid, depth, 1.0), np.nan)
    beside = np.zeros(band.shape, dtype=bool)
    claimed = np.zeros(band.shape, dtype=bool)
    for flip in (False, True):
        for transpose in (False, True):
            b, v, iv, out, cl = (_edge_view(a, transpose, flip) for a in (band, valid, inv, beside, claimed))
            n, m = b.shape
            run = np.where((~b).any(axis=1), (~b).argmax(axis=1), m)[:, None]
            # no run looks further in (a row all band has no strip): the views cut there, the band being narrow
            reach = min(3 * int(run[run < m].max(initial=0)), m)
            b, v, iv, out, cl = (a[:, :reach] for a in (b, v, iv, out, cl))
            col = np.arange(reach)[None, :]
            strip = (col >= run) & (col < 2 * run) & v & ~b & ~cl
            near = (col >= run) & (col < 3 * run) & v & ~b  # the strip and as far again beyond it
            jump = near[:, 1:] & near[:, :-1] & (np.abs(np.diff(iv, axis=1)) > step * np.fmax(iv[:, 1:], iv[:, :-1]))
            inside = col[:, 1:] < 2 * run  # the pair (c - 1, c) with c in the strip
            hit = (jump & ~inside).any(axis=1) & ~(jump & inside).any(axis=1)
            out[strip] = np.broadcast_to(hit[:, None], strip.shape)[strip]
            cl[strip] = True
    return beside


def choose_band(work, rgb, edge, band, border_width, pool: Executor | None = None) -> np.ndarray:
    """Per pixel of ``edge`` (the band to fill), the index in :data:`BAND_NAMES` of its fill, chosen per
    stretch of its edge by evidence from the capture (module docstring, 4.).

    The strip of valid depth just inside each stretch (:func:`band_strips`) is hidden, and band and
    strips are filled from the rest of the valid depth with each base fill (one solve each, at half
    resolution, :data:`BAND_SCALE`), bounded as the band is
    (:func:`~rgbd2scene.reconstruct.fill.solvers.clip_to_surround`); each stretch takes the candidate of
    :data:`BAND_CANDIDATES` with the least absolute error in inverse depth on its strip, the biharmonic fill
    (index 0) where the strip is empty or on a tie. Without RGB, the biharmonic or the harmonic fill.
    ``pool``: where the solves run (:func:`_base_fills`).
    """
    valid = valid_depth(work)
    seg_band = np.where(edge, band_strips(band, valid, BAND_STRETCH)[0], 0)
    sc = BAND_SCALE
    small = work[::sc, ::sc]
    seg_strip = band_strips(band[::sc, ::sc], valid[::sc, ::sc], BAND_STRETCH, scale=sc)[1]
    test = seg_strip > 0
    if not test.any():
        return np.zeros(work.shape, dtype=int)
    names = BAND_NAMES if rgb is not None else BAND_NAMES[:2]
    bases = sorted({b for k in names for b in BAND_CANDIDATES[k]})
    trial = np.where(test, np.nan, small).astype(np.float32)
    unknown = edge[::sc, ::sc] | test
    jobs = {b: (unknown, np.zeros(small.shape, dtype=bool)) for b in bases}
    fills = _base_fills(trial, None if rgb is None else rgb[::sc, ::sc], jobs, pool)
    fills = {b: clip_to_surround(f, trial, unknown, border_width // sc, BAND_MARGIN) for b, f in fills.items()}
    # errors in inverse depth (module docstring, 4.): in metres a strip's few far pixels outweigh the rest
    truth = 1.0 / small[test].astype(np.float64)
    owner = seg_strip[test]
    miss = np.abs(truth - 1.0 / float(np.nanmedian(work)))  # the error of a strip pixel left unfilled
    n = int(max(seg_band.max(), seg_strip.max())) + 1
    err = np.zeros((n, len(names)))
    for k, name in enumerate(names):
        est = 1.0 / np.mean([fills[b][test] for b in BAND_CANDIDATES[name]], axis=0).astype(np.float64)
        err[:, k] = np.bincount(owner, weights=np.where(np.isfinite(est), np.abs(est - truth), miss), minlength=n)
    # the membrane only where it beats the others clearly (:data:`BAND_MEMBRANE_MARGIN`)
    err[:, names.index("harmonic")] *= BAND_MEMBRANE_MARGIN
    choice = err.argmin(axis=1)  # argmin keeps the first (biharmonic) on a tie and where no strip was scored
    # a strip whose trial filled it from a sliver beside a step is no evidence for its band: the thin plate
    crossed = np.bincount(owner, weights=stepped_strips(band[::sc, ::sc], small)[test], minlength=n)
    choice[crossed > BAND_STEPPED_SHARE * np.bincount(owner, minlength=n)] = 0
    choice[0] = 0
    return choice[seg_band]
