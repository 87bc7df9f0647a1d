"""Depth hole filling for RGB-D captures (float32 metres, NaN = hole).

Methods (``FILL_METHODS``)
--------------------------
``inpaint``       ``cv2.inpaint`` (Navier-Stokes) on normalised inverse depth: the fast fallback.
``colorization``  Levin et al. colour-guided fill as in the NYU Depth v2 toolbox
                  (``fill_depth_colorization``), solved for the hole pixels only (valid pixels are
                  hard constraints): a small sparse system, about 0.1 s at 640x480.
``biharmonic``    thin-plate (biharmonic) fill of all holes in one sparse system: exact on planes.
``background``    for structured-light occlusion shadows: boundary pixels on the near side of a
                  depth step across a hole are dropped as constraints, so the hole is filled
                  (harmonically) from the far side of its boundary only.
``auto``          per hole and per hole row (see below); the default.
``none``          no filling; the holes stay NaN.

Every fill works on inverse depth (a plane is affine in pixel coordinates there) and never changes a
valid pixel. :func:`fill_harmonic` (membrane / Laplace fill) is available as well; ``auto`` uses it.

What ``auto`` does
------------------
1. **Depth steps**: a horizontal or vertical run of hole pixels bridges a step when its two valid end
   pixels differ by more than ``step`` (4 %) in inverse depth, even after extrapolating each side's
   slope across the run (a slanted floor is not a step), see :func:`step_runs`.
2. **Occlusion shadows** (:func:`shadow_pixels`): a horizontal step run no wider than the shadow a
   structured-light sensor casts there, fx * b * (1/z_near - 1/z_far) + 1 px, is filled by the
   background fill (from the far end). For a registered Kinect v1 image, b is 7.5 cm (projector to
   IR camera) for holes *left* of the near surface and 2.5 cm (IR to RGB camera) for holes right of
   it (``shadow_baselines``); fx defaults to 525 px scaled to the image width. In the real TUM frame
   the step-bridging hole runs left of a near surface have a median width of 0.96 times the 7.5 cm
   bound (shadows), those right of it 3.6 times (mostly dropouts), so wider runs are not shadows.
3. **Other holes with a step, and holes above ``big_hole_fraction``** (default 1 % of the image):
   colorization or biharmonic, whichever predicts better the valid depth hidden under the image's
   own hole masks shifted by (9, 13) px (a self-validation per image: colour edges follow depth
   edges in rooms, not on textured tissue). Without RGB: biharmonic.
4. **Small holes without a step**: harmonic fill (it averages sensor noise on the boundary; on the
   benchmark it beat biharmonic and colorization on such holes).
``FillResult.method`` names what was used, e.g. ``"auto: background+colorization+harmonic"``.

Which pixels are filled (recorded in ``FillResult.stats``)
----------------------------------------------------------
* **Interior holes** are filled by the chosen method.
* **Huge holes**: an interior hole larger than ``max_hole_fraction`` of the image (default 5 %, e.g.
  the far-range corridor hole of the SUN RGB-D sample) is left NaN: there is no surface to guess, and
  the mesh cuts it (``stats["huge_holes"]``, ``stats["huge_hole_fraction"]``).
* **Border band**: Kinect-style sensors leave a band of holes along the image edges (8-43 px wide in
  the TUM, NYU, SUN and Redwood samples). Hole pixels within ``border_width`` px of the edge (default
  10 % of the shorter side, 48 px at 640x480) that connect to the edge form the band; after the
  interior is filled, band pixels take the value of the nearest finite pixel (edge replication) if
  it is at most 1.5 ``border_width`` px away (1.5: corners), else they stay NaN.
  ``fill_border=False`` leaves the band NaN. Parts of an edge-connected hole beyond the band are
  interior holes.
* A hole with no valid pixel around it (e.g. enclosed by the band) stays NaN.
* The output holds NaN only in those places: ``stats["left_unfilled_fraction"]``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage as ndi
from scipy import sparse
from scipy.sparse.linalg import spsolve

from rgbd2scene.errors import UserError

FILL_METHODS = ("auto", "inpaint", "colorization", "biharmonic", "background", "none")

#: Registered Kinect v1: projector 7.5 cm right of the IR camera (shadows left of a near surface),
#: IR camera 2.5 cm left of the RGB camera (occlusions right of a near surface). Metres.
KINECT_SHADOW_BASELINES = (0.075, 0.025)
#: Kinect v1 focal length at 640 px width (PrimeSense default intrinsics).
KINECT_FX_640 = 525.0

_EIGHT = np.ones((3, 3), dtype=bool)
_FOUR = ndi.generate_binary_structure(2, 1)
_OFFSETS4 = [(-1, 0), (0, -1), (0, 1), (1, 0)]
#: Shift of the hole masks used by ``auto`` to self-validate colorization against biharmonic.
_PROBE_SHIFT = (9, 13)


@dataclass
class FillResult:
    """Outcome of :func:`fill_depth`.

    Attributes
    ----------
    depth : float32 (H, W) metres; NaN only where deliberately left unfilled (huge holes, far band).
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


# ----------------------------------------------------------------------------------------------
# helpers


def _as_depth(depth: np.ndarray) -> np.ndarray:
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.size == 0:
        raise UserError(f"--fill: depth must be a non-empty 2-D array, got shape {depth.shape}")
    if not np.issubdtype(depth.dtype, np.floating):
        raise UserError(f"--fill: depth must be float metres, got {depth.dtype}")
    return depth


def _valid(depth: np.ndarray) -> np.ndarray:
    """Usable depth: finite and positive."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth) & (depth > 0)


def _fill_mask(depth: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Pixels to fill: ``mask`` (default: every invalid pixel)."""
    if mask is None:
        return ~_valid(depth)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != depth.shape:
        raise ValueError(f"mask shape {mask.shape} differs from depth shape {depth.shape}")
    return mask


def _to_inverse(depth: np.ndarray, known: np.ndarray) -> np.ndarray:
    out = np.zeros(depth.shape, dtype=np.float64)
    out[known] = 1.0 / depth[known].astype(np.float64)
    return out


def _from_inverse(inv: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Inverse depth back to depth, clipped to a plausible range [lo, hi] metres."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = 1.0 / np.clip(inv, 1.0 / hi, 1.0 / lo)
    return z


def _depth_range(depth: np.ndarray, known: np.ndarray) -> tuple[float, float]:
    vals = depth[known]
    return 0.5 * float(vals.min()), 2.0 * float(vals.max())


def _grey(rgb: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if rgb is None:
        return None
    rgb = np.asarray(rgb)
    if rgb.shape[:2] != shape:
        raise UserError(f"--fill: RGB is {rgb.shape[1]}x{rgb.shape[0]} but depth is {shape[1]}x{shape[0]}")
    if rgb.ndim == 2:
        g = rgb.astype(np.float64)
    else:
        g = rgb[..., :3].astype(np.float64) @ np.array([0.2989, 0.5870, 0.1140])
    return g / (255.0 if rgb.dtype == np.uint8 else max(float(g.max()), 1e-12))


def _components(mask: np.ndarray) -> tuple[np.ndarray, int]:
    labels, n = ndi.label(mask, structure=_EIGHT)
    return labels, int(n)


def _finish(depth: np.ndarray, mask: np.ndarray, values: np.ndarray, solved: np.ndarray) -> np.ndarray:
    """Copy of ``depth`` with ``values`` written into the solved mask pixels (float32)."""
    out = np.array(depth, dtype=np.float32, copy=True)
    out[mask] = np.nan
    sel = mask & solved
    out[sel] = values[sel].astype(np.float32)
    return out


def _reachable(unknown: np.ndarray, known: np.ndarray, eight: bool = False) -> np.ndarray:
    """Unknown pixels whose 4- (or 8-) connected component touches at least one known pixel."""
    st = _EIGHT if eight else _FOUR
    labels, n = ndi.label(unknown, structure=st)
    if n == 0:
        return unknown.copy()
    touch = ndi.binary_dilation(known, structure=st) & unknown
    ok = np.zeros(n + 1, dtype=bool)
    ok[np.unique(labels[touch])] = True
    ok[0] = False
    return ok[labels]


def _shifted(rows: np.ndarray, cols: np.ndarray, dr: int, dc: int, shape) -> tuple:
    r2, c2 = rows + dr, cols + dc
    inside = (r2 >= 0) & (r2 < shape[0]) & (c2 >= 0) & (c2 < shape[1])
    return r2, c2, inside


def fill_inpaint(
    depth: np.ndarray, mask: np.ndarray | None = None, *, radius: float = 5.0, algorithm: str = "ns"
) -> np.ndarray:
    """Fill holes with ``cv2.inpaint`` on normalised inverse depth.

    Parameters
    ----------
    depth : float (H, W) metres, NaN (or <= 0) = invalid.
    mask : bool (H, W), pixels to fill; default every invalid pixel. Invalid pixels outside the mask
        are neither used nor filled (they stay NaN).
    radius : inpainting neighbourhood radius in pixels.
    algorithm : ``"telea"`` or ``"ns"`` (Navier-Stokes).

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    depth = _as_depth(depth)
    mask = _fill_mask(depth, mask)
    known = _valid(depth) & ~mask
    if not mask.any() or not known.any():
        return _finish(depth, mask, np.zeros(depth.shape), np.zeros(depth.shape, bool))
    lo, hi = _depth_range(depth, known)
    inv = _to_inverse(depth, known)
    vmin, vmax = float(inv[known].min()), float(inv[known].max())
    scale = max(vmax - vmin, 1e-12)
    norm = np.zeros(depth.shape, dtype=np.float32)
    norm[known] = ((inv[known] - vmin) / scale).astype(np.float32)
    holes = (~known).astype(np.uint8)
    if algorithm == "telea":
        # cv2.inpaint's Telea on float32 returns values far outside the boundary range (OpenCV 4.11),
        # so Telea runs on 16-bit codes; Navier-Stokes is fine on float32
        codes = np.round(norm * 65535.0).astype(np.uint16)
        res = cv2.inpaint(codes, holes, float(radius), cv2.INPAINT_TELEA).astype(np.float64) / 65535.0
    elif algorithm == "ns":
        res = cv2.inpaint(norm, holes, float(radius), cv2.INPAINT_NS).astype(np.float64)
    else:
        raise ValueError(f"unknown inpaint algorithm {algorithm!r} (telea or ns)")
    z = _from_inverse(res * scale + vmin, lo, hi)
    return _finish(depth, mask, z, _reachable(mask, known))


def _levin_weights(grey: np.ndarray, rows, cols, usable: np.ndarray, win_rad: int = 1):
    """Levin et al. affinities of each pixel (rows, cols) to its window neighbours.

    Returns a list of (r2, c2, w) per neighbour offset, with weights normalised over the usable
    neighbours as in ``fill_depth_colorization`` of the NYU Depth v2 toolbox.
    """
    shape = grey.shape
    offs = [(dr, dc) for dr in range(-win_rad, win_rad + 1) for dc in range(-win_rad, win_rad + 1)
            if (dr, dc) != (0, 0)]
    g0 = grey[rows, cols]
    nb = []
    gvals = np.full((len(offs), rows.size), np.nan)
    for k, (dr, dc) in enumerate(offs):
        r2, c2, inside = _shifted(rows, cols, dr, dc, shape)
        r2c, c2c = np.clip(r2, 0, shape[0] - 1), np.clip(c2, 0, shape[1] - 1)
        ok = inside & usable[r2c, c2c]
        gvals[k, inside] = grey[r2c[inside], c2c[inside]]
        nb.append((r2c, c2c, ok))
    allg = np.vstack([gvals, g0[None]])
    with np.errstate(invalid="ignore"):
        c_var = np.nanmean((allg - np.nanmean(allg, axis=0)) ** 2, axis=0)
        d2 = (gvals - g0) ** 2
        mgv = np.nanmin(d2, axis=0)
    csig = np.maximum(c_var * 0.6, -mgv / np.log(0.01))
    csig = np.maximum(np.nan_to_num(csig, nan=2e-6), 2e-6)
    w = np.exp(-np.nan_to_num(d2, nan=np.inf) / csig)
    oks = np.vstack([o[2] for o in nb])
    w = np.where(oks, w, 0.0)
    tot = w.sum(axis=0)
    # a pixel whose usable neighbours all got ~0 weight: uniform weights
    flat = tot < 1e-12
    if flat.any():
        w[:, flat] = oks[:, flat].astype(np.float64)
        tot = w.sum(axis=0)
    w = w / np.maximum(tot, 1e-300)
    return [(nb[k][0], nb[k][1], w[k]) for k in range(len(offs))]


def _colorization_solver(grey: np.ndarray, win_rad: int = 1):
    """Levin et al. colorization system over the unknown pixels, hard constraints on the known ones."""

    def solve(inv: np.ndarray, unknown: np.ndarray, known: np.ndarray) -> np.ndarray:
        rows, cols = np.nonzero(unknown)
        n = rows.size
        index = np.full(inv.shape, -1, dtype=np.int64)
        index[rows, cols] = np.arange(n)
        nbs = _levin_weights(grey, rows, cols, known | unknown, win_rad)
        ii, jj, vv = [np.arange(n)], [np.arange(n)], [np.ones(n)]
        rhs = np.zeros(n)
        for r2, c2, w in nbs:
            j = index[r2, c2]
            is_u = (j >= 0) & (w > 0)
            ii.append(np.nonzero(is_u)[0])
            jj.append(j[is_u])
            vv.append(-w[is_u])
            is_k = known[r2, c2] & (w > 0)
            rhs += np.where(is_k, w * inv[r2, c2], 0.0)
        A = sparse.csr_matrix((np.concatenate(vv), (np.concatenate(ii), np.concatenate(jj))), shape=(n, n))
        out = np.zeros(inv.shape)
        out[rows, cols] = spsolve(A.tocsc(), rhs)
        return out

    return solve


def _smooth_fill(depth, mask, solver, exclude=None, eight: bool = False) -> np.ndarray:
    """Run ``solver(inverse_depth, unknown, constraints)`` for the mask pixels.

    ``exclude``: valid pixels not used as constraints (nor as graph nodes: a free boundary there).
    Hole parts that touch only excluded pixels are filled from their whole boundary instead.
    """
    depth = _as_depth(depth)
    mask = _fill_mask(depth, mask)
    known = _valid(depth) & ~mask
    constraints = known if exclude is None else known & ~exclude
    unknown = mask & _reachable(mask, constraints, eight)
    rest = mask & ~unknown & _reachable(mask, known, eight) if exclude is not None else None
    if not unknown.any() and (rest is None or not rest.any()):
        return _finish(depth, mask, np.zeros(depth.shape), unknown)
    lo, hi = _depth_range(depth, known)
    vals = np.zeros(depth.shape)
    if unknown.any():
        vals = solver(_to_inverse(depth, constraints), unknown, constraints)
    if rest is not None and rest.any():
        vals[rest] = solver(_to_inverse(depth, known), rest, known)[rest]
        unknown = unknown | rest
    return _finish(depth, mask, _from_inverse(vals, lo, hi), unknown)


def fill_colorization(
    depth: np.ndarray,
    rgb: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    *,
    win_rad: int = 1,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """Colour-guided fill (Levin et al. colorization, as in the NYU Depth v2 toolbox).

    Each hole pixel equals the affinity-weighted mean of its window neighbours, the affinities coming
    from the grey image (``fill_depth_colorization``). Unlike the toolbox, valid pixels are hard
    constraints (kept exactly) and only the hole pixels are unknowns, which makes the sparse system
    small: it is solved with a direct sparse solver. Works on inverse depth.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    rgb : uint8 (H, W, 3) registered colour image; None gives uniform weights (a harmonic fill).
    mask : bool (H, W) pixels to fill, default every invalid pixel; other invalid pixels stay NaN.
    win_rad : window radius of the affinities (1 = 3x3, as in the toolbox).
    exclude : bool (H, W) valid pixels not to use as constraints (e.g. the near side of a shadow).

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    depth = _as_depth(depth)
    grey = _grey(rgb, depth.shape)
    if grey is None:
        grey = np.zeros(depth.shape)
    return _smooth_fill(depth, mask, _colorization_solver(grey, win_rad), exclude, eight=win_rad > 0)


def _thin_plate(inv: np.ndarray, unknown: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Minimise the squared graph Laplacian (thin-plate energy) over the unknown pixels.

    The Laplacian is evaluated at every domain pixel 4-adjacent to (or in) the unknown set, with the
    4-neighbours that lie in the domain (unknown or known); missing neighbours give a free boundary.
    """
    shape = inv.shape
    domain = unknown | known
    sites = ndi.binary_dilation(unknown, structure=_FOUR) & domain
    # only the domain pixels the sites touch matter
    touched = ndi.binary_dilation(sites, structure=_FOUR) & domain
    tr, tc = np.nonzero(touched)
    index = np.full(shape, -1, dtype=np.int64)
    index[tr, tc] = np.arange(tr.size)
    sr, sc = np.nonzero(sites)
    m = sr.size
    srow = np.arange(m)
    ii, jj, vv = [], [], []
    deg = np.zeros(m)
    for dr, dc in _OFFSETS4:
        r2, c2, inside = _shifted(sr, sc, dr, dc, shape)
        r2c, c2c = np.clip(r2, 0, shape[0] - 1), np.clip(c2, 0, shape[1] - 1)
        ok = inside & domain[r2c, c2c]
        ii.append(srow[ok])
        jj.append(index[r2c[ok], c2c[ok]])
        vv.append(np.ones(int(ok.sum())))
        deg += ok
    ii.append(srow)
    jj.append(index[sr, sc])
    vv.append(-deg)
    B = sparse.csr_matrix((np.concatenate(vv), (np.concatenate(ii), np.concatenate(jj))),
                          shape=(m, tr.size))
    is_u = unknown[tr, tc]
    Bu = B[:, np.nonzero(is_u)[0]]
    Bk = B[:, np.nonzero(~is_u)[0]]
    xk = inv[tr[~is_u], tc[~is_u]]
    A = (Bu.T @ Bu).tocsc()
    b = -(Bu.T @ (Bk @ xk))
    # a tiny Tikhonov term keeps degenerate holes (e.g. a one-pixel-wide line of constraints) solvable
    A = A + sparse.identity(A.shape[0], format="csc") * 1e-9
    x = spsolve(A, b)
    out = np.zeros(shape)
    out[tr[is_u], tc[is_u]] = x
    return out


def fill_biharmonic(
    depth: np.ndarray, mask: np.ndarray | None = None, *, exclude: np.ndarray | None = None
) -> np.ndarray:
    """Thin-plate (biharmonic) fill of inverse depth: smooth, and exact for planar surfaces.

    Agrees with ``skimage.restoration.inpaint_biharmonic`` (to 1e-5 relative on a test surface) and
    takes about as long as it does with ``split_into_regions=True`` (0.10 s against 0.12 s for the
    TUM frame's holes); this version also takes ``exclude`` and leaves non-mask holes out of the
    system (a free boundary there) instead of needing values in them.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    mask : bool (H, W) pixels to fill, default every invalid pixel; other invalid pixels stay NaN.
    exclude : bool (H, W) valid pixels not to use as constraints.

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    return _smooth_fill(depth, mask, _thin_plate, exclude)


def _membrane(inv: np.ndarray, unknown: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Harmonic fill: each unknown pixel is the mean of its usable 4-neighbours."""
    shape = inv.shape
    rows, cols = np.nonzero(unknown)
    n = rows.size
    index = np.full(shape, -1, dtype=np.int64)
    index[rows, cols] = np.arange(n)
    ii, jj, vv = [], [], []
    deg = np.zeros(n)
    rhs = np.zeros(n)
    for dr, dc in _OFFSETS4:
        r2, c2, inside = _shifted(rows, cols, dr, dc, shape)
        r2c, c2c = np.clip(r2, 0, shape[0] - 1), np.clip(c2, 0, shape[1] - 1)
        j = np.where(inside, index[r2c, c2c], -1)
        is_u = j >= 0
        is_k = inside & known[r2c, c2c]
        ii.append(np.nonzero(is_u)[0])
        jj.append(j[is_u])
        vv.append(-np.ones(int(is_u.sum())))
        rhs += np.where(is_k, inv[r2c, c2c], 0.0)
        deg += is_u | is_k
    ii.append(np.arange(n))
    jj.append(np.arange(n))
    vv.append(deg)
    A = sparse.csr_matrix((np.concatenate(vv), (np.concatenate(ii), np.concatenate(jj))), shape=(n, n))
    x = spsolve(A.tocsc(), rhs)
    out = np.zeros(shape)
    out[rows, cols] = x
    return out


def fill_harmonic(
    depth: np.ndarray, mask: np.ndarray | None = None, *, exclude: np.ndarray | None = None
) -> np.ndarray:
    """Harmonic (membrane, Laplace) fill of inverse depth: each hole pixel is the mean of its
    4-neighbours. Smoothest and most robust to boundary noise; flattens curved surfaces.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    mask : bool (H, W) pixels to fill, default every invalid pixel; other invalid pixels stay NaN.
    exclude : bool (H, W) valid pixels not to use as constraints.

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    return _smooth_fill(depth, mask, _membrane, exclude)


def _runs(mask: np.ndarray):
    """Horizontal runs of True: arrays row, start, stop (exclusive)."""
    pad = np.zeros((mask.shape[0], mask.shape[1] + 2), dtype=np.int8)
    pad[:, 1:-1] = mask
    d = np.diff(pad, axis=1)
    sr, sc = np.nonzero(d == 1)
    er, ec = np.nonzero(d == -1)
    return sr, sc, ec  # nonzero is row-major so starts and stops pair up


# ----------------------------------------------------------------------------------------------
# depth steps across holes


@dataclass
class StepRuns:
    """Runs of hole pixels (along a row or a column) with a depth step between their two ends.

    Arrays, one entry per run: ``axis`` (0: along a row, 1: along a column), ``line`` (the row or
    column index), ``start`` and ``stop`` (first hole index along the line and one past the last),
    ``near_first`` (the nearer end pixel is the one before ``start``).
    """

    axis: np.ndarray
    line: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    near_first: np.ndarray

    @property
    def length(self) -> np.ndarray:
        return self.stop - self.start

    def subset(self, keep: np.ndarray) -> StepRuns:
        return StepRuns(self.axis[keep], self.line[keep], self.start[keep], self.stop[keep],
                        self.near_first[keep])

    def end_depths(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Depth of the near and the far end pixel of each run."""
        h = self.axis == 0
        before, after = np.empty(h.size), np.empty(h.size)
        before[h] = depth[self.line[h], self.start[h] - 1]
        after[h] = depth[self.line[h], self.stop[h]]
        before[~h] = depth[self.start[~h] - 1, self.line[~h]]
        after[~h] = depth[self.stop[~h], self.line[~h]]
        return np.minimum(before, after), np.maximum(before, after)

    def near_ends(self, shape) -> np.ndarray:
        """bool (H, W): the valid end pixel on the near side of each run."""
        out = np.zeros(shape, dtype=bool)
        pos = np.where(self.near_first, self.start - 1, self.stop)
        h = self.axis == 0
        out[self.line[h], pos[h]] = True
        out[pos[~h], self.line[~h]] = True
        return out

    def pixels(self, shape) -> np.ndarray:
        """bool (H, W): the hole pixels of the runs."""
        n = self.length
        run = np.repeat(np.arange(n.size), n)
        pos = self.start[run] + np.arange(run.size) - np.repeat(np.cumsum(n) - n, n)
        h = self.axis[run] == 0
        out = np.zeros(shape, dtype=bool)
        out[np.where(h, self.line[run], pos), np.where(h, pos, self.line[run])] = True
        return out


def step_runs(depth: np.ndarray, mask: np.ndarray, step: float = 0.04, slope_px: int = 6) -> StepRuns:
    """The runs of ``mask`` pixels that bridge a depth step.

    A horizontal or vertical run of mask pixels with valid depth at both ends bridges a step when the
    ends differ by more than ``step`` (relative, in inverse depth), and still do after extrapolating
    either side's inverse-depth slope (measured over ``slope_px`` px beyond the end) across the run:
    a slanted surface is not a step.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    mask : bool (H, W), the hole pixels to analyse (other invalid pixels end no run).
    step : relative depth difference that makes a step.
    slope_px : baseline in px of the slope estimate beyond each end.

    Returns
    -------
    StepRuns
    """
    known = _valid(depth) & ~mask
    inv = np.where(known, 1.0 / np.where(known, depth, 1.0), np.nan)
    parts = []
    for axis in (0, 1):
        m = mask if axis == 0 else mask.T
        iv = inv if axis == 0 else inv.T
        r, c0, c1 = _runs(m)
        width = m.shape[1]
        ok = (c0 > 0) & (c1 < width)
        r, c0, c1 = r[ok], c0[ok], c1[ok]
        ia, ib = iv[r, c0 - 1], iv[r, c1]
        ok = np.isfinite(ia) & np.isfinite(ib)
        r, c0, c1, ia, ib = r[ok], c0[ok], c1[ok], ia[ok], ib[ok]
        lo = np.minimum(ia, ib)
        jump = np.maximum(ia, ib) > lo * (1 + step)
        # slopes beyond each end (inverse depth per px, pointing into the run); 0 where unknown
        ka = np.clip(c0 - 1 - slope_px, 0, width - 1)
        kb = np.clip(c1 + slope_px, 0, width - 1)
        za, zb = iv[r, ka], iv[r, kb]
        ga = np.where(np.isfinite(za) & (ka < c0 - 1), (ia - za) / np.maximum(c0 - 1 - ka, 1), 0.0)
        gb = np.where(np.isfinite(zb) & (kb > c1), (ib - zb) / np.maximum(kb - c1, 1), 0.0)
        span = (c1 - c0 + 1).astype(np.float64)
        miss = np.minimum(np.abs(ib - (ia + ga * span)), np.abs(ia - (ib + gb * span)))
        keep = jump & (miss > step * lo)
        parts.append((np.full(int(keep.sum()), axis), r[keep], c0[keep], c1[keep], (ia > ib)[keep]))
    return StepRuns(*(np.concatenate([p[i] for p in parts]) for i in range(5)))


def near_side(depth: np.ndarray, mask: np.ndarray, step: float = 0.04) -> np.ndarray:
    """bool (H, W): valid pixels at the near end of a depth step across a hole (see :func:`step_runs`)."""
    return step_runs(depth, mask, step).near_ends(depth.shape)


def shadow_pixels(
    runs: StepRuns, depth: np.ndarray, fx: float, baselines=KINECT_SHADOW_BASELINES, slack_px: float = 1.0
) -> np.ndarray:
    """Hole pixels of horizontal step runs no wider than an occlusion shadow can be there.

    A sensor whose projector (or second camera) sits a baseline b to the right of the camera the
    depth is registered to leaves a shadow fx * b * (1/z_near - 1/z_far) px wide on the far surface,
    left of the near one; one to the left leaves it right of the near surface.

    Parameters
    ----------
    runs : step runs from :func:`step_runs`.
    depth : float (H, W) metres.
    fx : focal length in px.
    baselines : (b for holes left of the near surface, b for holes right of it), metres; 0 disables.
    slack_px : extra width allowed, px.

    Returns
    -------
    bool (H, W)
    """
    b = np.where(runs.near_first, float(baselines[1]), float(baselines[0]))
    sub = runs.subset((runs.axis == 0) & (b > 0))
    b = b[(runs.axis == 0) & (b > 0)]
    zn, zf = sub.end_depths(depth)
    width = fx * b * (1.0 / zn - 1.0 / zf)
    return sub.subset(sub.length <= width + slack_px).pixels(depth.shape)


def fill_background(
    depth: np.ndarray,
    mask: np.ndarray | None = None,
    *,
    step: float = 0.04,
    exclude_radius: int = 2,
    smooth: str = "membrane",
) -> np.ndarray:
    """Fill occlusion shadows from the far side of their boundary.

    Structured-light sensors (Kinect) leave a shadow beside each depth step; it lies on the *far*
    surface. Boundary pixels on the near side of a step (see :func:`near_side`), and the valid pixels
    within ``exclude_radius`` of them on the same near surface (:func:`near_exclusion`), are dropped;
    the hole is then filled smoothly from the remaining (far) boundary, which extends the far
    surface into the shadow. Holes without a step are filled smoothly from their whole boundary.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    mask : bool (H, W) pixels to fill, default every invalid pixel.
    step : relative depth difference across a hole that counts as a step (0.04 = 4 %).
    exclude_radius : pixels around near-side boundary pixels also dropped as constraints.
    smooth : ``"membrane"`` (harmonic) or ``"thin_plate"`` (biharmonic) fill from the far side.

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    depth = _as_depth(depth)
    mask = _fill_mask(depth, mask)
    near = near_exclusion(depth, mask, near_side(depth, mask, step), step, exclude_radius)
    solver = _thin_plate if smooth == "thin_plate" else _membrane
    return _smooth_fill(depth, mask, solver, near)


def near_exclusion(depth, mask, near_ends, step: float = 0.04, radius: int = 2) -> np.ndarray:
    """The near-side end pixels of step runs plus the valid pixels within ``radius`` of them that lie
    on the near surface (not deeper than the nearest end by more than step/2)."""
    if radius <= 0 or not near_ends.any():
        return near_ends
    known = _valid(depth) & ~mask
    grown = ndi.binary_dilation(near_ends, structure=_EIGHT, iterations=radius)
    zmax_near = ndi.maximum_filter(np.where(near_ends, depth, 0.0), size=2 * radius + 1)
    with np.errstate(invalid="ignore"):
        return near_ends | (grown & known & (depth <= zmax_near * (1 + step / 2)))


def border_band(holes: np.ndarray, width: int) -> np.ndarray:
    """Hole pixels within ``width`` px of the image edge that connect (within that frame) to the edge."""
    frame = np.zeros(holes.shape, dtype=bool)
    if width <= 0:
        return frame
    frame[:width], frame[-width:], frame[:, :width], frame[:, -width:] = True, True, True, True
    cand = holes & frame
    labels, n = ndi.label(cand, structure=_EIGHT)
    if n == 0:
        return frame & False
    edge = np.zeros(holes.shape, dtype=bool)
    edge[0], edge[-1], edge[:, 0], edge[:, -1] = True, True, True, True
    ok = np.zeros(n + 1, dtype=bool)
    ok[np.unique(labels[edge & cand])] = True
    ok[0] = False
    return ok[labels]


def _extrapolate(depth: np.ndarray, target: np.ndarray, max_dist: float) -> np.ndarray:
    """Give ``target`` pixels the value of the nearest finite pixel within ``max_dist`` px."""
    out = depth.copy()
    finite = np.isfinite(out)
    if not finite.any() or not target.any():
        return out
    dist, (ri, ci) = ndi.distance_transform_edt(~finite, return_indices=True)
    sel = target & (dist <= max_dist)
    out[sel] = out[ri[sel], ci[sel]]
    return out


# ----------------------------------------------------------------------------------------------
# the pipeline


def fill_depth(
    depth: np.ndarray,
    rgb: np.ndarray | None = None,
    method: str = "auto",
    *,
    max_hole_fraction: float = 0.05,
    border_width: int | None = None,
    fill_border: bool = True,
    step: float = 0.04,
    fx: float | None = None,
    shadow_baselines: tuple[float, float] = KINECT_SHADOW_BASELINES,
    big_hole_fraction: float = 0.01,
    inpaint_radius: float = 5.0,
    inpaint_algorithm: str = "ns",
) -> FillResult:
    """Fill the holes of a depth map (see the module docstring for the methods and which pixels).

    Parameters
    ----------
    depth : float32 (H, W) metres, NaN = hole (non-positive values are holes too).
    rgb : uint8 (H, W, 3) registered colour image (colorization needs it; optional otherwise).
    method : one of ``FILL_METHODS``.
    max_hole_fraction : interior holes larger than this fraction of the image are left NaN.
    border_width : width in px of the edge band filled by extrapolation; default 10 % of the
        shorter image side (48 px at 640x480).
    fill_border : False leaves the edge band NaN.
    step : relative depth difference across a hole that counts as a depth step.
    fx : focal length in px for the shadow widths of ``auto``; default 525 px * width / 640.
    shadow_baselines : (b_left, b_right) metres, see :func:`shadow_pixels`; (0, 0) disables.
    big_hole_fraction : ``auto`` fills step-free holes larger than this fraction of the image with
        the self-validated colorization / biharmonic choice instead of the harmonic fill.
    inpaint_radius, inpaint_algorithm : ``cv2.inpaint`` radius (px) and ``"ns"`` or ``"telea"``.

    Returns
    -------
    FillResult
    """
    t0 = time.perf_counter()
    if method not in FILL_METHODS:
        raise UserError(f"--fill: unknown method {method!r}; choose one of {', '.join(FILL_METHODS)}")
    depth = _as_depth(depth)
    if not 0.0 < max_hole_fraction <= 1.0:
        raise UserError(f"--fill: max_hole_fraction must be in (0, 1], got {max_hole_fraction}")
    if inpaint_algorithm not in ("ns", "telea"):
        raise UserError(f"--fill: inpaint algorithm must be 'ns' or 'telea', got {inpaint_algorithm!r}")
    h, w = depth.shape
    npx = h * w
    border_width = int(round(0.1 * min(h, w))) if border_width is None else max(int(border_width), 0)
    fx = KINECT_FX_640 * w / 640.0 if fx is None else float(fx)
    _grey(rgb, depth.shape)  # checks the RGB size
    valid = _valid(depth)
    holes = ~valid
    work = np.where(valid, depth, np.nan).astype(np.float32)

    band = border_band(holes, border_width)
    interior = holes & ~band
    labels, n = _components(interior)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    sizes[0] = 0
    huge_ids = sizes > max_hole_fraction * npx
    huge = huge_ids[labels]
    todo = interior & ~huge

    used = method
    counts: dict[str, int] = {}
    validation: dict[str, float] = {}
    if method == "none" or not valid.any() or not todo.any():
        out = work.copy()
    elif method == "inpaint":
        out = fill_inpaint(work, todo, radius=inpaint_radius, algorithm=inpaint_algorithm)
    elif method == "colorization":
        out = fill_colorization(work, rgb, todo)
    elif method == "biharmonic":
        out = fill_biharmonic(work, todo)
    elif method == "background":
        out = fill_background(work, todo, step=step)
    else:
        out, counts, validation = _auto(work, rgb, todo, labels, sizes, step, fx, shadow_baselines,
                                        big_hole_fraction * npx)
        used = "auto: " + ("+".join(counts) if counts else "nothing to fill")
    if fill_border and method != "none" and band.any():
        out = _extrapolate(out, band, 1.5 * border_width)  # 1.5: the corners where two bands meet
    out[valid] = depth[valid]  # valid pixels are never changed
    filled = holes & np.isfinite(out)

    settings = {
        "method": method, "max_hole_fraction": float(max_hole_fraction), "border_width": border_width,
        "fill_border": bool(fill_border), "step": float(step), "fx": fx,
        "shadow_baselines": [float(b) for b in shadow_baselines], "big_hole_fraction": float(big_hole_fraction),
        "inpaint_radius": float(inpaint_radius), "inpaint_algorithm": inpaint_algorithm,
        "space": "inverse depth", "rgb": rgb is not None,
    }
    stats = {
        "hole_fraction": float(holes.mean()),
        "filled_fraction": float(filled.mean()),
        "left_unfilled_fraction": float((holes & ~filled).mean()),
        "n_holes": int(n),
        "border_band_fraction": float(band.mean()),
        "huge_holes": int(huge_ids.sum()),
        "huge_hole_fraction": float(huge.mean()),
        "auto_pixels": counts,
        "auto_validation_mae_mm": validation,
        "seconds": round(time.perf_counter() - t0, 4),
    }
    return FillResult(out.astype(np.float32), filled, used, settings, stats)


def _auto(work, rgb, todo, labels, sizes, step, fx, baselines, big_px):
    """``auto`` (module docstring): shadow rows -> background; holes with a step or big ones ->
    self-validated colorization or biharmonic; small step-free holes -> harmonic.

    Returns the filled depth, the number of pixels each method filled and the self-validation errors.
    """
    n = sizes.size - 1
    out = work.copy()
    counts: dict[str, int] = {}
    validation: dict[str, float] = {}
    runs = step_runs(work, todo, step)
    shadow = shadow_pixels(runs, work, fx, baselines) & todo
    if shadow.any():
        comps = np.zeros(n + 1, dtype=bool)
        comps[labels[shadow]] = True
        comps[0] = False
        out[shadow] = fill_background(work, comps[labels] & todo, step=step)[shadow]
        counts["background"] = int(shadow.sum())
    rest = todo & ~shadow
    comp_step = np.zeros(n + 1, dtype=bool)
    comp_step[labels[runs.pixels(work.shape)]] = True
    comp_step[0] = False
    guided = (comp_step | (sizes > big_px))[labels] & rest
    small = rest & ~guided
    if guided.any():
        name, errors = _validate(work, rgb, todo) if rgb is not None else ("biharmonic", {})
        validation.update(errors)
        fill = fill_biharmonic(out, guided) if name == "biharmonic" else fill_colorization(out, rgb, guided)
        out[guided] = fill[guided]
        counts[name] = int(guided.sum())
    if small.any():
        out[small] = fill_harmonic(out, small)[small]
        counts["harmonic"] = int(small.sum())
    return out, counts, validation


def _validate(work, rgb, holes, candidates=("colorization", "biharmonic"), shift=_PROBE_SHIFT):
    """The candidate that best predicts valid depth hidden under the holes' own shapes, shifted.

    Returns the name and each candidate's mean absolute error in mm on those probe pixels.
    """
    valid = np.isfinite(work)
    probe = np.roll(holes, shift, axis=(0, 1)) & valid & ~ndi.binary_dilation(~valid)
    if probe.sum() < 50:
        return candidates[0], {}
    inp = work.copy()
    inp[probe] = np.nan
    truth = work[probe].astype(np.float64)
    errors = {}
    for name in candidates:
        res = fill_biharmonic(inp, probe) if name == "biharmonic" else fill_colorization(inp, rgb, probe)
        v = res[probe]
        ok = np.isfinite(v)
        errors[name] = round(1000 * float(np.mean(np.abs(v[ok] - truth[ok]))), 3) if ok.any() else 1e9
    return min(errors, key=errors.get), errors
