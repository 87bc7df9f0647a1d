"""Hole-filling solvers: pure functions on depth arrays (float metres, NaN or <= 0 = invalid).

Each takes the depth, optionally a mask of the pixels to fill (default every invalid pixel; other
invalid pixels are neither used nor filled), and returns a float32 copy with the mask pixels filled
where a solution exists (a mask region touching no valid pixel stays NaN). Every fill but the NYU
toolbox's works on inverse depth, where a plane is affine in pixel coordinates; none changes a valid pixel.

``fill_inpaint``          ``cv2.inpaint`` (Navier-Stokes) on normalised inverse depth: the fast fallback.
``fill_colorization``     Levin et al. colour-guided fill after the NYU Depth v2 toolbox's affinities,
                          solved for the hole pixels only (valid pixels kept as hard constraints).
``fill_nyu_colorization`` the NYU Depth v2 toolbox's ``fill_depth_colorization`` itself: the whole image,
                          known pixels as a soft data term, one sparse solve, in depth (not inverse depth).
``fill_biharmonic``       thin-plate (biharmonic) fill: smooth, exact on planes.
``fill_guided_thin_plate`` the thin plate with colour-weighted second differences: exact on planes, no slope
                          carried across a colour edge.
``smooth_rim``            the valid pixels round the holes with white noise smoothed away (a local quadratic fit).
``clip_to_rim``           each hole's fill bounded by its rim's depth range (a thin plate overshoots at steps).
``clip_to_surround``      each pixel's fill bounded by the depth range of the valid pixels around it, widened
                          by a margin (a thin plate extrapolated towards the image edge overshoots).
``fill_harmonic``         membrane (Laplace) fill: smoothest, most robust to boundary noise.
``fill_background``       for occlusion shadows: the near side of each depth step across a hole is
                          dropped as a constraint, so the hole is filled from the far side only.
``fill_row_background``   each horizontal run of hole pixels takes the depth of its farther end.
"""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from scipy import ndimage as ndi
from scipy import sparse
from scipy.sparse.linalg import splu, spsolve

from rgbd2scene.reconstruct.fill import cholmod
from rgbd2scene.reconstruct.fill.holes import (
    STEP,
    near_exclusion,
    near_side,
    reachable,
    row_runs,
    run_cells,
    valid_depth,
)

_FOUR = ndi.generate_binary_structure(2, 1)
_OFFSETS4 = [(-1, 0), (0, -1), (0, 1), (1, 0)]


def as_depth(depth: np.ndarray) -> np.ndarray:
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.size == 0:
        raise ValueError(f"depth must be a non-empty 2-D array, got shape {depth.shape}")
    if not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"depth must be float metres, got {depth.dtype}")
    return depth


def _fill_mask(depth: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Pixels to fill: ``mask`` (default: every invalid pixel)."""
    if mask is None:
        return ~valid_depth(depth)
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


def check_rgb_size(rgb: np.ndarray | None, shape: tuple[int, int]) -> None:
    """ValueError unless ``rgb`` (if any) has the depth's ``shape`` (H, W)."""
    size = shape if rgb is None else np.shape(rgb)[:2]
    if size != shape:
        raise ValueError(f"RGB is {size[1]}x{size[0]} but depth is {shape[1]}x{shape[0]}")


def grey_levels(rgb: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if rgb is None:
        return None
    rgb = np.asarray(rgb)
    check_rgb_size(rgb, shape)
    if rgb.ndim == 2:
        g = rgb.astype(np.float64)
    else:
        g = rgb[..., :3].astype(np.float64) @ np.array([0.2989, 0.5870, 0.1140])
    return g / (255.0 if rgb.dtype == np.uint8 else max(float(g.max()), 1e-12))


def _finish(depth: np.ndarray, mask: np.ndarray, values: np.ndarray, solved: np.ndarray) -> np.ndarray:
    """Copy of ``depth`` with ``values`` written into the solved mask pixels (float32)."""
    out = np.array(depth, dtype=np.float32, copy=True)
    out[mask] = np.nan
    sel = mask & solved
    out[sel] = values[sel].astype(np.float32)
    return out


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
    depth = as_depth(depth)
    mask = _fill_mask(depth, mask)
    known = valid_depth(depth) & ~mask
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
    return _finish(depth, mask, z, reachable(mask, known))


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
    depth = as_depth(depth)
    mask = _fill_mask(depth, mask)
    known = valid_depth(depth) & ~mask
    constraints = known if exclude is None else known & ~exclude
    unknown = mask & reachable(mask, constraints, eight)
    rest = mask & ~unknown & reachable(mask, known, eight) if exclude is not None else None
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
    depth = as_depth(depth)
    grey = grey_levels(rgb, depth.shape)
    if grey is None:
        grey = np.zeros(depth.shape)
    return _smooth_fill(depth, mask, _colorization_solver(grey, win_rad), exclude, eight=win_rad > 0)


_OFFSETS8 = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def nyu_affinities(grey: np.ndarray, nodes: np.ndarray,
                   at: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The affinities of ``fill_depth_colorization`` (NYU Depth v2 toolbox, after Levin et al.).

    For each pixel r and each 8-neighbour s in the graph, w_rs = exp(-(I_r - I_s)^2 / sigma_r), normalised
    to sum to 1 over r's neighbours, where sigma_r = 0.6 * the variance of I over the 3x3 window (r and
    its neighbours), raised to at least min_s (I_r - I_s)^2 / ln(100) (so that the closest neighbour
    keeps a weight of 0.01 or more) and to at least 2e-6, exactly as the toolbox does it.

    Parameters
    ----------
    grey : float (H, W) grey levels in [0, 1].
    nodes : bool (H, W) the graph's pixels; a pixel outside it is nobody's neighbour.
    at : (rows, cols) the pixels whose weights to compute (None: every pixel). The solve needs them on the
        graph's pixels only, often a third of its bounding box or less; each weight is the same to the bit
        (the same operations, element by element).

    Returns
    -------
    float64 (8, H, W): the weight of each neighbour offset (:data:`_OFFSETS8` order), 0 where the
    neighbour is outside the image or the graph; with ``at``, float64 (8, n) for its n pixels.
    """
    h, w = grey.shape
    padded = np.pad(np.where(nodes, grey, np.nan), 1, constant_values=np.nan)
    # in blocks of about AFFINITY_BLOCK pixels: each block's (8, n) arrays stay in the cache (the same operations
    # element by element, so the same bits)
    if at is None:
        weights = np.empty((8, h, w))
        for r0, block in _affinity_rows(grey, padded, max(AFFINITY_BLOCK // w, 1)):
            weights[:, r0:r0 + block.shape[1]] = block
        return weights
    rows, cols = at
    weights = np.empty((8, rows.size))
    # gathered by flat index (a third of the time of a 2-D index), the same values
    flat, stride = padded.ravel(), w + 2
    for i0 in range(0, rows.size, AFFINITY_BLOCK):
        r, c = rows[i0:i0 + AFFINITY_BLOCK], cols[i0:i0 + AFFINITY_BLOCK]
        centre = (r + 1) * stride + c + 1
        nb = np.stack([flat[centre + (dr * stride + dc)] for dr, dc in _OFFSETS8])
        weights[:, i0:i0 + AFFINITY_BLOCK] = _affinity_block(nb, grey[r, c])
    return weights


#: :func:`nyu_affinities` works on blocks of this many pixels (8 x 16k float64: 1 MB an array, in the cache).
AFFINITY_BLOCK = 16384


def _affinity_rows(grey: np.ndarray, padded: np.ndarray, step: int):
    """:func:`nyu_affinities` of every pixel, ``step`` rows at a time: yields (first row, float64 (8, rows, W));
    ``padded``: the grey levels on the graph, NaN elsewhere and around the image."""
    h, w = grey.shape
    for r0 in range(0, h, step):
        r1 = min(r0 + step, h)
        nb = np.stack([padded[1 + dr + r0:1 + dr + r1, 1 + dc:1 + dc + w] for dr, dc in _OFFSETS8])
        yield r0, _affinity_block(nb, grey[r0:r1])


def _affinity_block(nb: np.ndarray, grey: np.ndarray) -> np.ndarray:
    """:func:`nyu_affinities` of the pixels whose grey levels are ``grey`` (shape S) and whose 8 neighbours'
    are ``nb`` (8, *S; NaN: no neighbour), worked on in place."""
    off = np.isnan(nb)
    nbz = nb  # np.stack's own copy
    np.copyto(nbz, 0.0, where=off)
    count = 8.0 - off.sum(axis=0) + 1.0
    mean = (nbz.sum(axis=0) + grey) / count
    dev = np.subtract(nbz, mean)
    np.copyto(dev, 0.0, where=off)
    var = (np.square(dev, out=dev).sum(axis=0) + (grey - mean) ** 2) / count
    d2 = np.subtract(nbz, grey, out=dev)
    np.square(d2, out=d2)
    np.copyto(d2, np.inf, where=off)
    closest = d2.min(axis=0)
    closest[~np.isfinite(closest)] = 0.0
    sigma = np.maximum(np.maximum(0.6 * var, closest / -np.log(0.01)), 2e-6)
    weights = np.exp(np.divide(np.negative(d2, out=d2), sigma, out=d2), out=d2)  # exp(-inf) = 0 off the graph
    total = weights.sum(axis=0)
    weights /= np.where(total > 0, total, 1.0)
    return weights


#: :func:`_nyu_solve`: the known pixels within this many px of an unknown one are solved with the unknowns by one
#: sparse LU (the overlap of the two blocks; six benchmark inputs to 1e-8 m: 4-5 rounds at 1 px, 4 at 2 px, 3-4 at
#: 3 px, the LU 7 % larger a px: CPU 4.27, 3.71, 4.27 s in all).
NYU_RING = 2
#: :func:`_nyu_solve`: four-colour Gauss-Seidel sweeps over the known pixels between two LU solves (each cuts the
#: known pixels' error by about 4; 3, 4, 6 sweeps: 5, 4, 3 rounds to 1e-8 m on the TUM frame, about the same time).
NYU_SWEEPS = 4
#: :func:`_nyu_solve`: rounds (LU solve, sweeps) before the direct solve of the whole system is used instead (its
#: bound shrinks by 1/300 to 1/1000 a round on the benchmark's captures: never reached there).
NYU_ROUNDS = 60
#: :func:`_nyu_parts`: N is factorised in two parts side by side only where the smaller part's LU costs at least this
#: share of the whole (below it the second thread saves little)...
NYU_SPLIT = 0.15
#: ... and N has at least this many pixels (a thread's start and the second dissection cost about 1 ms).
NYU_SPLIT_SIZE = 20000
#: :func:`_nyu_solve` relaxes on the image's colour planes where the graph fills at least this share of its bounding
#: box, on its own pixels (a sparse product, Jacobi) where less (``auto``'s band graph on the TUM frame: 12 % of the
#: image, 2x slower on the planes than GMRES was).
NYU_DENSE = 0.5


def _nyu_matrix(weights: np.ndarray, nodes: np.ndarray, known: np.ndarray, alpha: float) -> sparse.csr_matrix:
    """The toolbox's matrix I - W + alpha G over the pixels of ``nodes`` in row-major order (``weights``:
    :func:`nyu_affinities`, (8, H, W)): the system :func:`_nyu_solve` solves, for a direct solve."""
    h, w = nodes.shape
    index = np.full((h + 2, w + 2), -1, dtype=np.int64)
    rows, cols = np.nonzero(nodes)
    index[rows + 1, cols + 1] = np.arange(rows.size)
    ii, jj = [np.arange(rows.size)], [np.arange(rows.size)]
    vv = [np.where(known[rows, cols], 1.0 + alpha, 1.0)]
    for k, (dr, dc) in enumerate(_OFFSETS8):
        j = index[rows + 1 + dr, cols + 1 + dc]
        use = j >= 0
        ii.append(np.flatnonzero(use))
        jj.append(j[use])
        vv.append(-weights[k][rows[use], cols[use]])
    return sparse.csr_matrix((np.concatenate(vv), (np.concatenate(ii), np.concatenate(jj))),
                             shape=(rows.size, rows.size))


def _nyu_error_bound(res: np.ndarray, layer_starts: np.ndarray, layer_weights: np.ndarray) -> float:
    """Bound on the error of the unknown pixels (:func:`_nyu_solve`): the far pixels' absolute residuals ``res``,
    ordered by their distance D to the unknown pixels (each distance starting at ``layer_starts``), the largest of
    each distance times its weight (1 + alpha)^-(D - 1) / alpha, summed."""
    if res.size == 0:
        return 0.0
    return float(layer_weights @ np.maximum.reduceat(res, layer_starts))


def _colour_planes(image: np.ndarray, pad: int = 0) -> np.ndarray:
    """(..., H, W) -> (..., 2, 2, (H + 1) // 2 + 2 pad, (W + 1) // 2 + 2 pad): the image's four colours (row and
    column parity; pixels of one colour are never 8-neighbours), pixel (r, c) at [r % 2, c % 2, r // 2 + pad,
    c // 2 + pad], zero around and beyond the image."""
    h, w = image.shape[-2:]
    out = np.zeros((*image.shape[:-2], 2, 2, (h + 1) // 2 + 2 * pad, (w + 1) // 2 + 2 * pad), dtype=image.dtype)
    for a in (0, 1):
        for c in (0, 1):
            part = image[..., a::2, c::2]
            out[..., a, c, pad:pad + part.shape[-2], pad:pad + part.shape[-1]] = part
    return out


def _nyu_affinity_planes(grey: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """:func:`nyu_affinities` of every pixel (the same bits), laid out as :func:`_colour_planes` with ``pad=1``:
    float64 (8, 2, 2, (H + 1) // 2 + 2, (W + 1) // 2 + 2)."""
    h, w = grey.shape
    padded = np.pad(np.where(nodes, grey, np.nan), 1, constant_values=np.nan)
    out = np.zeros((8, 2, 2, (h + 1) // 2 + 2, (w + 1) // 2 + 2))
    step = max(AFFINITY_BLOCK // w // 2 * 2, 2)  # an even number of rows: each block starts on colour row 0
    for r0, block in _affinity_rows(grey, padded, step):
        for a in (0, 1):
            for c in (0, 1):
                part = block[:, a::2, c::2]
                out[:, a, c, 1 + r0 // 2:1 + r0 // 2 + part.shape[1], 1:1 + part.shape[2]] = part
    return out


def _nyu_parts(inside: np.ndarray) -> list[np.ndarray]:
    """N (:func:`_nyu_solve`) as one part, or as two parts of whole 8-connected components (no coupling between them)
    whose LU costs are about equal: the largest components first, each to the part with the smaller cost so far, a
    component's cost taken as its size^1.5 (a nested dissection's on a grid); two parts only where the smaller
    costs at least :data:`NYU_SPLIT` of the whole and N has :data:`NYU_SPLIT_SIZE` pixels or more."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(inside.astype(np.uint8), connectivity=8)
    cost = stats[1:, cv2.CC_STAT_AREA].astype(np.float64) ** 1.5
    if count < 3 or stats[1:, cv2.CC_STAT_AREA].sum() < NYU_SPLIT_SIZE:
        return [inside]
    part, load = np.zeros(count, dtype=np.int64), [0.0, 0.0]
    for i in np.argsort(-cost, kind="stable"):
        part[i + 1] = int(load[1] < load[0])
        load[part[i + 1]] += cost[i]
    if min(load) < NYU_SPLIT * sum(load):
        return [inside]
    second = part[labels] == 1
    return [inside & ~second, second]


def _dissected(part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pixels of ``part`` in nested dissection order (:func:`dissection_order`, a 3x3 stencil)."""
    rows, cols = np.nonzero(part)
    order = dissection_order(rows, cols, reach=1)
    return rows[order], cols[order]


def _nyu_block(pixels: tuple[np.ndarray, np.ndarray], flat_weights: np.ndarray, plane_index: np.ndarray,
               known: np.ndarray, padded_far: np.ndarray, b: np.ndarray, alpha: float, size: int) -> tuple:
    """The LU of N's block over ``pixels`` (rows, columns in elimination order; :func:`_nyu_solve`), with what its
    solve needs: (LU, the pixels' places in the solution vector, their right-hand side, their coupling to F as a
    sparse matrix over its ``size`` places); ``plane_index``: each pixel of the image padded by one pixel -> its
    place, ``flat_weights`` (8, size) the affinities at each place (:func:`_plane_relaxation`)."""
    h, w = known.shape
    # the block by columns: column j (pixel p) holds A[q, p] = -w_{7-k}(q) for its neighbour q = p + offset k
    # (offset 7 - k leads from q back to p)
    nr, nc = pixels
    n = nr.size
    stride = w + 2
    centre = (nr + 1) * stride + nc + 1  # flat indices into the image padded by one pixel
    position = np.full((h + 2) * stride, -1, dtype=np.int64)
    position[centre] = np.arange(n)
    rows = np.empty((n, 9), dtype=np.int64)
    values = np.empty((n, 9))
    rows[:, 8] = np.arange(n)
    values[:, 8] = np.where(known[nr, nc], 1.0 + alpha, 1.0)
    coupling_i, coupling_j, coupling_v = [], [], []  # the rows' entries in F's columns (planes' flat indices)
    n_planes = plane_index[centre]
    for k, (dr, dc) in enumerate(_OFFSETS8):
        q = centre + dr * stride + dc
        rows[:, k] = position[q]
        values[:, k] = -flat_weights[7 - k][plane_index[q]]
        to_far = np.flatnonzero(padded_far[q])
        coupling_i.append(to_far)
        coupling_j.append(plane_index[q[to_far]])
        coupling_v.append(flat_weights[k][n_planes[to_far]])
    present = rows >= 0
    A = sparse.csc_matrix((values[present], rows[present], np.concatenate([[0], np.cumsum(present.sum(axis=1))])),
                          shape=(n, n))
    A.sort_indices()
    coupling = sparse.csr_matrix((np.concatenate(coupling_v), (np.concatenate(coupling_i),
                                                                np.concatenate(coupling_j))), shape=(n, size))
    return _diagonal_pivot_lu(A, ordered=True), n_planes, b[nr, nc], coupling


def _plane_relaxation(grey: np.ndarray, nodes: np.ndarray, graph_known: np.ndarray, b: np.ndarray, x0: np.ndarray,
                      alpha: float) -> tuple:
    """:func:`_nyu_solve`'s unknowns and relaxation on the four colour planes of the image (:func:`_colour_planes`):
    ``(x, index, weights, residual, relax, image)``: x the flat solution vector, ``index`` each pixel of the image
    padded by one pixel -> its place in x (pixels around the image: a padding cell, 0), ``weights`` (8, x.size) the
    affinities at each place, ``residual()`` b + W x - (1 + alpha) x at every place, ``relax()`` :data:`NYU_SWEEPS`
    four-colour Gauss-Seidel sweeps over the known pixels, ``image()`` x as an (H, W) image."""
    h, w = nodes.shape
    hp, wp = (h + 1) // 2, (w + 1) // 2
    weights = _nyu_affinity_planes(grey, nodes)
    rows, cols = np.arange(h)[:, None], np.arange(w)
    index = np.pad(((rows % 2 * 2 + cols % 2) * (hp + 2) + rows // 2 + 1) * (wp + 2) + cols // 2 + 1, 1).ravel()
    x = _colour_planes(x0, pad=1)
    b_planes, known_planes = _colour_planes(b), _colour_planes(graph_known)

    def neighbours(a: int, c: int, dr: int, dc: int) -> np.ndarray:
        """The plane view of colour (a, c)'s neighbours at offset (dr, dc): colour ((a + dr) % 2, (c + dc) % 2),
        ((a + dr) // 2, (c + dc) // 2) away in its plane."""
        (ra, si), (ca, sj) = divmod(a + dr, 2)[::-1], divmod(c + dc, 2)[::-1]
        return x[ra, ca, 1 + si:1 + si + hp, 1 + sj:1 + sj + wp]

    colours = [(a, c, [(weights[k, a, c, 1:-1, 1:-1], neighbours(a, c, dr, dc))
                       for k, (dr, dc) in enumerate(_OFFSETS8)]) for a in (0, 1) for c in (0, 1)]
    acc, part = np.empty((hp, wp)), np.empty((hp, wp))
    res = np.zeros(x.shape)

    def weighted(a: int, c: int, terms: list) -> np.ndarray:
        """Colour (a, c)'s b + W x."""
        np.copyto(acc, b_planes[a, c])
        for wk, view in terms:
            np.add(acc, np.multiply(wk, view, out=part), out=acc)
        return acc

    def residual() -> np.ndarray:
        for a, c, terms in colours:
            np.subtract(weighted(a, c, terms), (1.0 + alpha) * x[a, c, 1:-1, 1:-1], out=res[a, c, 1:-1, 1:-1])
        return res.ravel()

    def relax() -> None:
        for _ in range(NYU_SWEEPS):
            for a, c, terms in colours:
                np.copyto(x[a, c, 1:-1, 1:-1], np.multiply(weighted(a, c, terms), 1.0 / (1.0 + alpha), out=acc),
                          where=known_planes[a, c])

    def image() -> np.ndarray:
        out = np.empty((2 * hp, 2 * wp))
        for a in (0, 1):
            for c in (0, 1):
                out[a::2, c::2] = x[a, c, 1:-1, 1:-1]
        return out[:h, :w]

    return x.ravel(), index, weights.reshape(8, -1), residual, relax, image


def _node_relaxation(grey: np.ndarray, nodes: np.ndarray, graph_known: np.ndarray, b: np.ndarray, x0: np.ndarray,
                     alpha: float) -> tuple:
    """As :func:`_plane_relaxation` on the graph's pixels alone (a sparse graph in its bounding box: ``auto``'s graphs
    of the pixels near its holes, a tenth to a third of the box): x holds one place per graph pixel (row-major) and a
    last place, 0, for every pixel outside the graph; ``relax()`` is 2 :data:`NYU_SWEEPS` Jacobi sweeps (each cuts
    the error by about 2, a Gauss-Seidel sweep by about 4) by a sparse product over the known pixels' rows."""
    h, w = nodes.shape
    gr, gc = np.nonzero(nodes)
    m = gr.size
    weights = np.zeros((8, m + 1))
    weights[:, :m] = nyu_affinities(grey, nodes, at=(gr, gc))
    stride = w + 2
    index = np.full((h + 2) * stride, m, dtype=np.int64)
    index[(gr + 1) * stride + gc + 1] = np.arange(m)
    x = np.zeros(m + 1)
    x[:m] = x0[gr, gc]
    known = np.flatnonzero(graph_known[gr, gc])
    centre = (gr[known] + 1) * stride + gc[known] + 1
    columns = np.stack([index[centre + dr * stride + dc] for dr, dc in _OFFSETS8], axis=1)
    W = sparse.csr_matrix((weights[:, known].T.ravel(), columns.ravel(), np.arange(0, 8 * known.size + 1, 8)),
                          shape=(known.size, m + 1))
    b_known = b[gr[known], gc[known]]
    res = np.zeros(m + 1)

    def residual() -> np.ndarray:
        res[known] = b_known + W @ x - (1.0 + alpha) * x[known]
        return res

    def relax() -> None:
        for _ in range(2 * NYU_SWEEPS):
            x[known] = (b_known + W @ x) / (1.0 + alpha)

    def image() -> np.ndarray:
        out = np.zeros((h, w))
        out[gr, gc] = x[:m]
        return out

    return x, index, weights, residual, relax, image


def _nyu_solve(depth: np.ndarray, grey: np.ndarray, nodes: np.ndarray, known: np.ndarray, alpha: float,
               tol: float) -> np.ndarray:
    """Solve the toolbox's system (I - W + alpha G) x = alpha G d over the ``nodes`` (G: the known pixels) until
    the unknown pixels are provably within ``tol`` (metres) of its exact solution.

    Overlapping blocks: N, the unknown pixels and the known ones within :data:`NYU_RING` px of them, is solved
    exactly by one sparse LU (nested dissection order) given the other known pixels F; then the known pixels
    (F and N's ring: the overlap) are relaxed given the unknown ones; and again. The rows of known pixels are
    diagonally dominant (1 + alpha against at most 1), which bounds the error: after N's solve, an error e_F on F
    moves the unknown pixels by at most (1 + alpha)^-(r - 1) max|e_F| where r is the distance from F to them (a
    known pixel's error is at most 1 / (1 + alpha) of its neighbours' largest, an unknown one's at most its
    neighbours' largest), and max|e_F| <= max|residual on F| / alpha; summed over the layers of F at each distance
    D, the residuals of the far layers count by (1 + alpha)^-(D - 1) (:func:`_nyu_error_bound`). It stops when that
    bound is at most ``tol`` (the bound falls by 1/300 to 1/1000 a round on the benchmark's captures, from about
    0.2 m after the first: 4 rounds to 1e-8 m). Until session 20: GMRES over the whole system preconditioned by the
    unknowns' LU, 10-13 iterations to a relative residual of 1e-9, 4e-8 m from the direct solve on the TUM frame
    with a large hole (here 2.4e-10 m at the default tolerance).

    The relaxation works on the four colour planes of the image (:func:`_plane_relaxation`) where the graph fills at
    least :data:`NYU_DENSE` of its bounding box, else on the graph's pixels alone (:func:`_node_relaxation`). A
    second thread computes the affinities while N is ordered, and factorises the second part of N where it falls
    into two (:func:`_nyu_parts`; half of the benchmark's inputs).
    """
    h, w = depth.shape
    unknown = nodes & ~known
    graph_known = nodes & known
    b = np.zeros((h, w))
    b[graph_known] = alpha * depth[graph_known].astype(np.float64)
    x0 = np.where(graph_known, depth, 0.0).astype(np.float64)
    relaxation = _plane_relaxation if nodes.mean() >= NYU_DENSE else _node_relaxation
    with ThreadPoolExecutor(1) as pool:  # a second core: the affinities while N is ordered, a second part's LU
        prepared = pool.submit(relaxation, grey, nodes, graph_known, b, x0, alpha)
        distance = cv2.distanceTransform((~unknown).astype(np.uint8), cv2.DIST_C, 3)  # px to the nearest unknown
        inside = unknown | (graph_known & (distance <= NYU_RING))
        far = graph_known & ~inside
        parts = [_dissected(part) for part in _nyu_parts(inside)]
        flat, index, weights, residual, relax, image = prepared.result()
        shared = (weights, index, known, np.pad(far, 1).ravel(), b, alpha, flat.size)
        second = [pool.submit(_nyu_block, part, *shared) for part in parts[1:]]
        blocks = [_nyu_block(parts[0], *shared)] + [block.result() for block in second]
    # F by distance to the unknown pixels, for the bound (a stable sort of 16-bit integers: a radix sort)
    fr, fc = np.nonzero(far)
    layer = distance[fr, fc].astype(np.int16)
    by_layer = np.argsort(layer, kind="stable")
    f_index, layer = index[(fr[by_layer] + 1) * (w + 2) + fc[by_layer] + 1], layer[by_layer]
    layer_starts = np.flatnonzero(np.r_[True, layer[1:] != layer[:-1]]) if layer.size else np.zeros(0, np.int64)
    layer_weights = (1.0 + alpha) ** -(layer[layer_starts].astype(np.float64) - 1.0) / alpha
    for _ in range(NYU_ROUNDS):
        for lu, n_index, b_inside, coupling in blocks:
            flat[n_index] = lu.solve(b_inside + coupling @ flat)
        if _nyu_error_bound(np.abs(residual()[f_index]), layer_starts, layer_weights) <= tol:
            return np.where(nodes, image(), np.nan)
        relax()
    # not within tol (never seen): the direct solve
    out = np.full((h, w), np.nan)
    matrix = _nyu_matrix(nyu_affinities(grey, nodes), nodes, known, alpha)
    out[nodes] = spsolve(matrix.tocsc(), b[nodes])
    return out


def fill_nyu_colorization(
    depth: np.ndarray,
    rgb: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    *,
    alpha: float = 1.0,
    rtol: float = 1e-8,
    reach: int | None = None,
) -> np.ndarray:
    """``fill_depth_colorization`` of the NYU Depth v2 toolbox (Silberman et al. 2012, after Levin et al.
    2004), at full resolution.

    Unknowns are every pixel of the graph, known ones included: each pixel should equal the
    affinity-weighted mean of its 3x3 neighbours (:func:`nyu_affinities`, from the grey image), and each
    known pixel its measured depth, with weight ``alpha``; one sparse solve of
    (I - W + alpha G) x = alpha G d, in depth (metres; the toolbox scales by the largest depth, which
    changes nothing). The graph is the whole image for the default mask, as in the toolbox; with a
    mask, the valid pixels and the mask pixels (other invalid pixels are left out). Only the mask pixels
    are written: valid pixels keep their measured depth, not the system's smoothed value. Solved until the
    filled pixels are provably within ``rtol`` times the largest known depth of the system's exact solution
    (:func:`_nyu_solve`; TUM frame with a large hole, default ``rtol``: at most 4.5e-8 m, 1e-10 m seen).

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    rgb : uint8 (H, W, 3) registered colour image; None gives uniform weights.
    mask : bool (H, W) pixels to fill, default every invalid pixel.
    alpha : weight of the data term on the known pixels (the toolbox's default, 1).
    rtol : error bound of the filled pixels against the exact solution, relative to the largest known depth
        (before session 21: GMRES's relative residual, default 1e-9; 4e-8 m from the direct solve on the TUM
        frame with a large hole).
    reach : only the known pixels within this many px of a mask pixel join the graph (None: all of them,
        as in the toolbox). A known pixel's value in the solution is half its depth plus half its
        neighbours' mean, so the influence of the pixels left out shrinks by about half per pixel: at
        ``reach=16`` the fill of the TUM frame's holes moves by at most 2e-4 mm (and session 20's GMRES solve
        cost half as much).

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled (those without a valid pixel
    connected to them stay NaN).
    """
    depth = as_depth(depth)
    mask = _fill_mask(depth, mask)
    valid = valid_depth(depth)
    known = valid & ~mask
    grey = grey_levels(rgb, depth.shape)
    if grey is None:
        grey = np.zeros(depth.shape)
    nodes = known | reachable(mask, known, eight=True)
    if reach is not None:
        near = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_C, 3) <= reach
        nodes &= near
    if not (nodes & mask).any():
        return _finish(depth, mask, np.zeros(depth.shape), np.zeros(depth.shape, bool))
    rows, cols = np.nonzero(nodes.any(axis=1))[0], np.nonzero(nodes.any(axis=0))[0]
    box = np.s_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]  # the graph's bounding box: the same system
    x = np.full(depth.shape, np.nan)
    scale = float(np.max(depth[nodes & known]))  # rtol is relative to the largest known depth
    x[box] = _nyu_solve(depth[box], grey[box], nodes[box], known[box], float(alpha), rtol * scale)
    return _finish(depth, mask, x, nodes & mask)


def _diagonal_pivot_lu(A: sparse.csc_matrix, ordered: bool = False):
    """SuperLU factorisation with a minimum degree ordering of A + A^T and the diagonal as pivots, for a matrix
    symmetric in structure that needs no row exchanges (symmetric positive definite, or diagonally dominant);
    ``ordered``: A's rows and columns are in elimination order already (:func:`dissection_order`), no ordering."""
    return splu(A, permc_spec="NATURAL" if ordered else "MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                options=dict(SymmetricMode=True))


def _spd_solve(A: sparse.csc_matrix, b: np.ndarray, ordered: bool = False) -> np.ndarray:
    """Solve A x = b for a symmetric positive definite A by a supernodal sparse Cholesky factorisation (CHOLMOD,
    :mod:`~rgbd2scene.reconstruct.fill.cholmod`) in approximate minimum degree order, or, ``ordered``, in the
    order of A's unknowns (:func:`dissection_order`).

    The TUM frame's joint thin plate of holes and band (57696 unknowns): 0.10-0.13 s CPU against 0.35-0.45 s for
    SuperLU's LU without row exchanges (:func:`_diagonal_pivot_lu`), the guided thin plate (26.8k, ``ordered``)
    0.04-0.06 s against 0.16-0.17 s; the solutions agree to 1e-10 relative (the guided plate, whose 1e-12 nudge
    leaves it ill-conditioned, to 1e-6 relative, both with residuals of 2e-15). Where CHOLMOD meets a pivot that
    is not positive (A only semi-definite in floating point) or cannot run (no cvxopt; out of memory), a warning
    says so and SuperLU's LU solves it as before."""
    reason = "CHOLMOD (cvxopt) is not available"
    if cholmod.available():
        try:
            return cholmod.spd_solve(A, b, cholmod.NATURAL if ordered else cholmod.AMD)
        except (cholmod.NotPositiveDefinite, RuntimeError) as err:  # RuntimeError: out of memory, or too large
            reason = f"CHOLMOD: {err}"
    warnings.warn(f"{reason}: solved by SuperLU's LU instead", RuntimeWarning, stacklevel=2)
    return _diagonal_pivot_lu(A, ordered).solve(b)


#: A box of at most this many unknowns ends :func:`dissection_order`'s bisection (smaller leaves: about as many
#: entries in L + U, larger ones (64) 6 % more on the TUM frame's guided thin plate).
DISSECTION_LEAF = 8


def dissection_order(rows: np.ndarray, cols: np.ndarray, reach: int, leaf: int = DISSECTION_LEAF) -> np.ndarray:
    """A nested dissection ordering of pixels whose system couples only pixels less than ``reach`` + 1 px apart
    along each axis: the pixels' bounding box is cut across its longer side by a separator ``reach`` px wide,
    each side cut again the same way until at most ``leaf`` pixels are left; each side is ordered before the
    other, both before their separator (no coupling crosses a separator, so eliminating one side fills nothing
    in the other).

    Parameters
    ----------
    rows, cols : int (n,) the pixels' coordinates.
    reach : the widest coupling of the system, in px along an axis (2 for a stencil spanning 5 x 5 pixels).
    leaf : boxes of at most this many pixels are not cut (ordered by their index).

    Returns
    -------
    int (n,): the pixels' indices in elimination order.
    """
    rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
    n = rows.size
    key = np.zeros(n, dtype=np.int64)  # base-3 digits per cut: 0 first side, 1 second side, 2 separator
    box = np.zeros(n, dtype=np.int64)  # each uncut pixel's box, numbered 0 .. boxes - 1
    live = np.arange(n)  # the pixels whose box is still cut
    far = int(max(rows.max(), cols.max())) + 1 if n else 0
    while live.size:  # each cut halves a box's longer side: about log2(rows * cols) rounds
        key *= 3  # every key one digit longer: a settled pixel's later digits 0
        b = box[live]
        boxes = int(b.max()) + 1
        r, c = rows[live], cols[live]
        lo_r, hi_r, lo_c, hi_c = (np.full(boxes, fill, dtype=np.int64) for fill in (far, -1, far, -1))
        np.minimum.at(lo_r, b, r)
        np.maximum.at(hi_r, b, r)
        np.minimum.at(lo_c, b, c)
        np.maximum.at(hi_c, b, c)
        across_rows = (hi_r - lo_r) >= (hi_c - lo_c)
        x = np.where(across_rows[b], r, c)
        cut = ((np.where(across_rows, lo_r + hi_r, lo_c + hi_c) + 1 - reach) // 2)[b]
        digit = np.where(x < cut, 0, np.where(x >= cut + reach, 1, 2))
        small = np.bincount(b, minlength=boxes)[b] <= leaf
        digit[small] = 0
        key[live] += digit
        go = ~small & (digit < 2)
        live, halves = live[go], 2 * b[go] + digit[go]
        seen = np.zeros(2 * boxes, dtype=bool)
        seen[halves] = True
        box[live] = (np.cumsum(seen) - 1)[halves]
    return np.argsort(key, kind="stable") if n else np.zeros(0, dtype=np.int64)


def _dilated(mask: np.ndarray, structure: np.ndarray) -> np.ndarray:
    """``ndi.binary_dilation(mask, structure)`` for a symmetric 3 x 3 ``structure`` (one step, nothing beyond the
    image) by ``cv2.dilate``: the same pixels in a tenth of the time (640x480: 3 ms against 0.3 ms)."""
    return cv2.dilate(mask.astype(np.uint8), structure.astype(np.uint8)).astype(bool)


def _split_columns(v: np.ndarray, i: np.ndarray, j: np.ndarray, m: int, is_u: np.ndarray,
                   order: np.ndarray | None = None):
    """The (m, n) CSR matrix of the triplets (``v``, ``i``, ``j``) split into its columns where ``is_u`` and the rest:
    ``B[:, is_u]``, ``B[:, ~is_u]``, each built from its own triplets (the same canonical matrices, entries and order,
    without CSR column indexing: 40 ms less per fill of the TUM frame). ``order``: the first part's columns taken in
    this order (``B[:, is_u][:, order]``)."""
    u = is_u[j]
    index = [np.cumsum(part) - 1 for part in (is_u, ~is_u)]  # each column's index within its part
    if order is not None:
        rank = np.empty(order.size, dtype=np.int64)
        rank[order] = np.arange(order.size)
        index[0] = rank[index[0]]  # (-1 before the first unknown column: never read)
    return tuple(sparse.csr_matrix((v[sel], (i[sel], at[j[sel]])), shape=(m, int(part.sum())))
                 for sel, part, at in ((u, is_u, index[0]), (~u, ~is_u, index[1])))


def _thin_plate(inv: np.ndarray, unknown: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Minimise the squared graph Laplacian (thin-plate energy) over the unknown pixels.

    The Laplacian is evaluated at every domain pixel 4-adjacent to (or in) the unknown set, with the
    4-neighbours that lie in the domain (unknown or known); missing neighbours give a free boundary.
    """
    shape = inv.shape
    domain = unknown | known
    sites = _dilated(unknown, _FOUR) & domain
    # only the domain pixels the sites touch matter
    touched = _dilated(sites, _FOUR) & domain
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
    is_u = unknown[tr, tc]
    Bu, Bk = _split_columns(np.concatenate(vv), np.concatenate(ii), np.concatenate(jj), m, is_u)
    xk = inv[tr[~is_u], tc[~is_u]]
    A = (Bu.T @ Bu).tocsc()
    b = -(Bu.T @ (Bk @ xk))
    # a tiny Tikhonov term keeps degenerate holes (e.g. a one-pixel-wide line of constraints) solvable
    A = A + sparse.identity(A.shape[0], format="csc") * 1e-9
    x = _spd_solve(A, b)
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
    system (a free boundary there) instead of needing values in them. The system is symmetric positive
    definite: :func:`_spd_solve`.

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


_AXES = [((0, 1), 1.0), ((1, 0), 1.0), ((1, 1), 0.5), ((1, -1), 0.5)]  # (step, 1 / step length^2 of a diagonal)


def _guided_plate_solver(grey: np.ndarray, contrast: float, floor: float):
    """Weighted least squares of each pixel's second differences along the 4 axes of its 3x3 window (the thin
    plate's energy), each weighted by exp(-(dI_a^2 + dI_b^2) / contrast^2) + floor, dI the grey difference of
    its two ends to the centre: exact on affine inverse depth whatever the weights; known pixels fixed."""

    def solve(inv: np.ndarray, unknown: np.ndarray, known: np.ndarray) -> np.ndarray:
        shape = inv.shape
        domain = unknown | known
        # the terms that hold an unknown are centred on a domain pixel in or 8-adjacent to the unknown set
        sites = _dilated(unknown, np.ones((3, 3), dtype=bool)) & domain
        sr, sc = np.nonzero(sites)
        touched = np.zeros((shape[0] + 2, shape[1] + 2), dtype=bool)
        for dr, dc in [(0, 0), *_OFFSETS8]:
            touched[1 + dr + sr, 1 + dc + sc] = True
        tr, tc = np.nonzero(touched[1:-1, 1:-1] & domain)
        index = np.full((shape[0] + 2, shape[1] + 2), -1, dtype=np.int64)  # padded: -1 off the image
        index[1 + tr, 1 + tc] = np.arange(tr.size)
        gpad = np.pad(grey, 1)
        g0 = grey[sr, sc]
        centre = index[1 + sr, 1 + sc]
        ii, jj, vv = [], [], []
        rows = 0
        for (dr, dc), scale in _AXES:
            a = index[1 + dr + sr, 1 + dc + sc]
            b = index[1 - dr + sr, 1 - dc + sc]
            use = (a >= 0) & (b >= 0)
            d2 = (gpad[1 + dr + sr, 1 + dc + sc] - g0) ** 2 + (gpad[1 - dr + sr, 1 - dc + sc] - g0) ** 2
            wgt = scale * np.sqrt(np.exp(-d2[use] / contrast ** 2) + floor)
            e = int(use.sum())
            term = rows + np.arange(e)
            ii += [term, term, term]
            jj += [a[use], b[use], centre[use]]
            vv += [wgt, wgt, -2.0 * wgt]
            rows += e
        is_u = unknown[tr, tc]
        ur, uc = tr[is_u], tc[is_u]
        # the unknowns in nested dissection order (each term spans 3 x 3 pixels, so A couples pixels up to 2 px apart):
        # on the TUM frame's 27k unknowns CHOLMOD's factorisation and solve in this order 39-41 ms CPU against 72-75 ms
        # in its minimum degree order (with SuperLU: 4.0M entries in L + U against 4.7M, 0.25 s against 0.4 s)
        order = dissection_order(ur, uc, reach=2)
        Bu, Bk = _split_columns(np.concatenate(vv), np.concatenate(ii), np.concatenate(jj), rows, is_u, order)
        A = (Bu.T @ Bu).tocsc()
        b = -(Bu.T @ (Bk @ inv[tr[~is_u], tc[~is_u]]))
        # a nudge relative to the diagonal keeps degenerate holes solvable (and a plane exact where all weights
        # are near the floor: an absolute one would pull such a hole towards zero)
        A = A + sparse.diags(1e-12 * np.maximum(A.diagonal(), 1e-300), format="csc")
        # SPD: a Cholesky factorisation
        out = np.zeros(shape)
        out[ur[order], uc[order]] = _spd_solve(A, b, ordered=True)
        return out

    return solve


def fill_guided_thin_plate(
    depth: np.ndarray,
    rgb: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    *,
    contrast: float = 0.02,
    floor: float = 1e-6,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """Colour-guided thin plate: the biharmonic fill's second-order energy with colour-weighted couplings.

    Minimises, over the hole pixels of inverse depth (valid pixels fixed), the sum over every pixel r in or
    next to a hole and every axis e of its 3x3 window (horizontal, vertical, both diagonals) of
    ``w * (x[r+e] - 2 x[r] + x[r-e])^2`` (diagonals scaled by 1/2 for their length), with
    ``w = exp(-((I[r+e] - I[r])^2 + (I[r-e] - I[r])^2) / contrast^2) + floor`` from the grey levels I in [0, 1].
    Each term vanishes on a plane in inverse depth, so a plane is filled exactly whatever the colours; where
    the colour is uniform all weights are 1 and it is a thin plate (continues slopes, exact on planes); a term
    that spans a colour edge all but drops out, so a slope does not carry across an object's outline (the plain
    thin plate's overshoot) and the surface on each side of the edge continues its own plane, as far as the
    colour shows it. Unlike the colorization it is not bounded by the rim's depths (a thin plate): clip it per
    hole where that matters (:func:`clip_to_rim`). Works on inverse depth; one sparse SPD solve.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    rgb : uint8 (H, W, 3) registered colour image; None: every weight 1 (a thin plate on the 3x3 window).
    mask : bool (H, W) pixels to fill, default every invalid pixel; other invalid pixels stay NaN.
    contrast : the grey difference (0-1) at which a coupling falls to 1/e: 0.02 is 5 of 255 levels, so any
        visible edge cuts it (0.05 and 0.1 did worse on the benchmark's tuning rows).
    floor : the weight every term keeps: it ties a region that colour edges cut off from every valid pixel
        to its neighbours, and caps how far the colour may bend the surface.
    exclude : bool (H, W) valid pixels not to use as constraints.

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    depth = as_depth(depth)
    grey = grey_levels(rgb, depth.shape)
    if grey is None:
        grey = np.zeros(depth.shape)
    return _smooth_fill(depth, mask, _guided_plate_solver(grey, float(contrast), float(floor)), exclude, eight=True)


_QUADRATIC = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]  # powers of (column, row) offsets


def smooth_rim(depth: np.ndarray, mask: np.ndarray, noise: float, *, sigma: float = 3.0, width: float = 6.0,
               gate: float = 3.0) -> np.ndarray:
    """The valid pixels within ``width`` px of ``mask`` with their noise smoothed away: each takes the value at
    its own position of a quadratic in inverse depth fitted to the valid pixels round it, weighted by a Gaussian
    of ``sigma`` px (exact on a quadratic, so a noise-free curved surface keeps its values).

    A thin plate treats each rim pixel as exact and carries its noise, as a slope, into the hole; from the
    smoothed rim it carries the surface's slope. A pixel keeps its measured depth where the fit's weighted root
    mean square residual exceeds ``gate`` times the noise (a depth step or an outline in its window: no quadratic
    fits there, and smoothing would blur the step).

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    mask : bool (H, W) the pixels to be filled (their rim is smoothed; other invalid pixels stay invalid).
    noise : the capture's relative noise (:func:`~rgbd2scene.reconstruct.fill.planes.sensor_noise`).
    sigma : px, the Gaussian's standard deviation (the window reaches 3 sigma). ``auto``'s tuning rows (the tissue
        sample's, its white noise): 3 px and ``width`` 6 px 0.6672 of the best reference (geometric mean), 2 px and
        4 or 6 px 0.6680, 4 px and 8 px 0.6705, 6 px and 12 px 0.6885 and 14 rows above 1.10 instead of 5 (its
        highlights lie on bulges that a wide window flattens); main 0.6773 (``fill.md``, session 12).
    width : px, how far from ``mask`` the rim reaches.
    gate : the largest residual, in multiples of the noise, at which a pixel is smoothed.

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the rim's pixels smoothed.
    """
    depth = as_depth(depth)
    mask = np.asarray(mask, dtype=bool)
    valid = valid_depth(depth) & ~mask
    out = np.array(depth, dtype=np.float32, copy=True)
    rim = valid & (cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3) <= width)
    if not rim.any():
        return out
    reach = int(np.ceil(3 * sigma))
    rows, cols = np.nonzero(rim)
    box = np.s_[max(rows.min() - reach, 0):rows.max() + reach + 1, max(cols.min() - reach, 0):cols.max() + reach + 1]
    weight = valid[box].astype(np.float64)
    inv = np.where(valid[box], 1.0 / np.where(valid[box], depth[box], 1.0), 0.0)
    at = rim[box]
    offsets = np.arange(-reach, reach + 1) / sigma  # in sigmas: the normal equations stay well conditioned
    gauss = np.exp(-0.5 * offsets**2)
    taps = [gauss * offsets**k for k in range(5)]

    def moment(image: np.ndarray, power: tuple[int, int]) -> np.ndarray:
        # correlation, not convolution: the sum over the window of image(p + o) * g(o) * o^power
        return cv2.sepFilter2D(image, cv2.CV_64F, taps[power[0]], taps[power[1]], borderType=cv2.BORDER_CONSTANT)[at]

    k = len(_QUADRATIC)
    moments: dict[tuple[int, int], np.ndarray] = {}
    normal = np.empty((int(at.sum()), k, k))
    rhs = np.empty((normal.shape[0], k))
    for i, (ci, ri) in enumerate(_QUADRATIC):
        for j, (cj, rj) in enumerate(_QUADRATIC):
            power = (ci + cj, ri + rj)
            if power not in moments:
                moments[power] = moment(weight, power)
            normal[:, i, j] = moments[power]
        rhs[:, i] = moment(weight * inv, (ci, ri))
    # a nudge relative to the weight keeps a pixel whose valid neighbours lie on a line solvable
    normal += 1e-9 * normal[:, :1, :1] * np.eye(k)
    coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
    raw = inv[at]
    residual = np.maximum(moment(weight * inv * inv, (0, 0)) - (coef * rhs).sum(axis=1), 0.0) / moments[(0, 0)]
    smooth = np.where(np.sqrt(residual) <= gate * noise * raw, coef[:, 0], raw)
    out[box][at] = (1.0 / smooth).astype(np.float32)
    return out


def clip_to_rim(filled: np.ndarray, depth: np.ndarray, mask: np.ndarray, width: float = 2.0) -> np.ndarray:
    """Each hole's fill clipped to the depth range of its rim: the valid pixels within ``width`` px of it.

    A harmonic fill obeys this bound by itself (the maximum principle); a thin plate does not, and
    across a depth step it overshoots beyond both sides.

    Parameters
    ----------
    filled : float (H, W) a fill of ``depth``'s ``mask`` pixels.
    depth : float (H, W) metres before the fill, NaN = invalid.
    mask : bool (H, W) the filled pixels; each 8-connected component is one hole.
    width : px, the rim's width.

    Returns
    -------
    float32 (H, W): ``filled`` with its mask pixels clipped (a hole without a valid rim unchanged).
    """
    out = np.array(filled, dtype=np.float32, copy=True)
    labels, lo, hi = rim_range(depth, mask, width)
    sel = mask & np.isfinite(out)
    out[sel] = np.clip(out[sel], lo[labels[sel]], hi[labels[sel]])
    return out


def rim_range(depth: np.ndarray, mask: np.ndarray, width: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The holes of ``mask`` (8-connected components: int (H, W), 0 = none) and each one's rim's least and
    greatest depth (float (n + 1,), inf and -inf for a hole without a valid rim): the valid pixels of
    ``depth`` within ``width`` px of it (:func:`clip_to_rim`)."""
    labels, n = ndi.label(mask, structure=np.ones((3, 3), dtype=bool))
    lo, hi = np.full(n + 1, np.inf), np.full(n + 1, -np.inf)
    if n == 0:
        return labels, lo, hi
    dist, (rows, cols) = ndi.distance_transform_edt(labels == 0, return_indices=True)
    rim = (dist <= width) & valid_depth(depth) & ~mask
    owner = labels[rows[rim], cols[rim]]
    np.minimum.at(lo, owner, depth[rim])
    np.maximum.at(hi, owner, depth[rim])
    return labels, lo, hi


def clip_to_surround(filled: np.ndarray, depth: np.ndarray, mask: np.ndarray, radius: int,
                     margin: float = 0.1) -> np.ndarray:
    """Each mask pixel's fill clipped to the depth range of the valid pixels within ``radius`` px of it
    (a square window), widened by ``margin``: [min / (1 + margin), max * (1 + margin)].

    A thin plate extrapolated from the surface towards the image edge continues the slope of inverse
    depth; where the surface recedes, inverse depth runs towards zero and depth grows without bound
    (the benchmark's TUM frame under the SUN mask: 18.7 m beside a far wall at 7.5 m). Unlike
    :func:`clip_to_rim` the bound is per pixel and leaves room beyond the surface's range, as a sloping
    surface does continue past its rim (a bound without the margin: the tissue sample's transplanted
    bands 1.10 -> 1.21 times the best reference).

    Parameters
    ----------
    filled : float (H, W) a fill of ``depth``'s ``mask`` pixels.
    depth : float (H, W) metres before the fill, NaN = invalid (its valid pixels bound the fill).
    mask : bool (H, W) the pixels to clip.
    radius : px, half the window's side; at least the band's width, so that each band pixel sees its rim.
    margin : relative room beyond the surrounding range.

    Returns
    -------
    float32 (H, W): ``filled`` with its mask pixels clipped (a pixel with no valid depth around unchanged).
    """
    out = np.array(filled, dtype=np.float32, copy=True)
    sel = np.asarray(mask, dtype=bool) & np.isfinite(out)
    if not sel.any():
        return out
    valid = valid_depth(depth)
    size = 2 * int(radius) + 1
    hi = _window_extreme(np.where(valid, depth, -np.inf), size, cv2.dilate, ndi.maximum_filter)[sel] * (1.0 + margin)
    lo = _window_extreme(np.where(valid, depth, np.inf), size, cv2.erode, ndi.minimum_filter)[sel] / (1.0 + margin)
    seen = np.isfinite(hi) & np.isfinite(lo)
    out[sel] = np.where(seen, np.clip(out[sel], lo, hi), out[sel])
    return out


def _window_extreme(a: np.ndarray, size: int, morph, fallback) -> np.ndarray:
    """The greatest (``cv2.dilate``) or least (``cv2.erode``) value of ``a`` in the ``size`` x ``size`` window round
    each pixel, as ``fallback`` (``ndi.maximum_filter`` / ``minimum_filter``) gives it, to the bit: their borders
    (replicated, reflected) repeat pixels the window already holds. OpenCV's is 2-4 times as fast (TUM frame, a
    97 px window: 13 ms against 3-6 ms); ``fallback`` for the types it does not take."""
    if a.dtype not in (np.float32, np.float64):
        return fallback(a, size=size)
    return morph(a, np.ones((size, size), dtype=np.uint8), borderType=cv2.BORDER_REPLICATE)


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
    # symmetric positive definite: every unknown pixel is connected to a known one (_smooth_fill)
    x = _spd_solve(A.tocsc(), rhs)
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


def fill_background(
    depth: np.ndarray,
    mask: np.ndarray | None = None,
    *,
    step: float = STEP,
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
    step : relative depth difference across a hole that counts as a step (``holes.STEP``, 4 %).
    exclude_radius : pixels around near-side boundary pixels also dropped as constraints.
    smooth : ``"membrane"`` (harmonic) or ``"thin_plate"`` (biharmonic) fill from the far side.

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    depth = as_depth(depth)
    mask = _fill_mask(depth, mask)
    near = near_exclusion(depth, mask, near_side(depth, mask, step), step, exclude_radius)
    solver = _thin_plate if smooth == "thin_plate" else _membrane
    return _smooth_fill(depth, mask, solver, near)


def fill_row_background(depth: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Fill each horizontal run of mask pixels with the depth of its farther valid end pixel (its only
    valid end where the other is the image edge or another hole): a shadow beside a depth step lies on
    the far surface.

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    mask : bool (H, W) pixels to fill, default every invalid pixel; runs without a valid end stay NaN.

    Returns
    -------
    float32 (H, W): a copy of ``depth`` with the mask pixels filled.
    """
    depth = as_depth(depth)
    mask = _fill_mask(depth, mask)
    known = valid_depth(depth) & ~mask
    z = np.where(known, depth, np.nan).astype(np.float64)
    rows, start, stop = row_runs(mask)
    width = mask.shape[1]
    before = np.where(start > 0, z[rows, np.maximum(start - 1, 0)], np.nan)
    after = np.where(stop < width, z[rows, np.minimum(stop, width - 1)], np.nan)
    value = np.fmax(before, after)  # the farther end; the only one where the other is NaN
    run, cols = run_cells(start, stop)
    values = np.full(depth.shape, np.nan)
    values[rows[run], cols] = value[run]
    return _finish(depth, mask, values, np.isfinite(values))
