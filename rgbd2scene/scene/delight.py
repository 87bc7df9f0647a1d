"""De-lighting a scope capture's texture: its own light's shading divided out, an albedo for the render.

An endoscope photographs tissue lit by its own light at the camera, so the capture image (the mesh's texture)
holds that light's shading: inverse-square fall-off with the distance, the cosine of the incidence angle and the
spot's cone. The render lights the texture again with the modelled light at the tip, so at the capture's own
pose the shading would count twice. :func:`delight_texture` divides it out, per texel (each vertex of the grid mesh
is one texel: its UV is that pixel's centre), in linear light:

    E = sum over the outlets of  spot(angle to the light's axis) * max(n . l, 0) / r^2
    albedo = texture_linear * E_ref / max(E, E_ref / MAX_GAIN)

with the same light model the render builds (:class:`~rgbd2scene.scene.model.Light`: its outlets, Blender's
inverse-square fall-off and spot cone, ``spot_mask``) and the mesh's angle-weighted vertex normals (the normals
Blender's smooth shading interpolates). ``E_ref`` is the median of E over the meshed texels the light reaches:
the median texel keeps its value, so the texture's level, which the light's power and the exposure defaults
were chosen for, stays about where it was (the ratio of the mean linear levels is recorded), and rendering at
the capture pose gives the capture image back up to one exposure factor (the auto exposure's) wherever the
clamp and the smoothing did not act.
The median, not a mean-preserving level: a level that keeps the mean has no solution when many texels lie
outside the spot's cone (their gain is the clamp's, whatever the level), and it would follow the few texels
of tiny E.

Smoothing: the shading is divided out low-passed, a Gaussian of ``DELIGHT_SMOOTH_PX`` (5) texels over the meshed
texels. Stereo depth is noisy at the pixel scale (below the matcher's window, about width / 100), so the mesh's
per-vertex normals are too: divided out per vertex, the inverse of that noise lands in the albedo (a worm-like
pattern in the texture). It cancels exactly when the render shades the same normals from the same light, at the
capture pose only; along any other path it adds to the render's own shading of the noise. On the Hamlyn twin
(capture pose) per vertex scores better (``benchmarks/results/twin.md``), which is that cancellation.

The clamp: a texel's gain (E_ref / E) is at most ``MAX_GAIN`` (4, two stops). It acts where the surface is at a
grazing angle to the light (cosine near 0: the depth's normals are least reliable there), where the spot's cone
ends, and on surfaces facing away from the light (lit only by interreflection in the capture); without it such
texels would become arbitrarily bright. Texels no vertex sits on (never rendered, or only at a mesh edge through
texture filtering) take the gain of the nearest meshed texel. Linear values above 1 clip when encoded back to
8-bit sRGB; the share is recorded.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

from rgbd2scene.geometry.mesh import vertex_normals
from rgbd2scene.scene.model import SPOT_BLEND, Light
from rgbd2scene.sensor.tone import srgb_decode, srgb_encode

#: The largest gain the division may apply to a texel (see the module docstring): two stops.
MAX_GAIN = 4.0
#: Gaussian sigma (texels) of the shading map divided out (see the module docstring).
DELIGHT_SMOOTH_PX = 5.0
DELIGHT_MODES = ("auto", "on", "off")


def spot_mask(cos_axis: np.ndarray, spot_size_deg: float, blend: float = SPOT_BLEND) -> np.ndarray:
    """Blender's spot cone (Cycles and EEVEE alike): smoothstep of (cos - cos_half) / ((1 - cos_half) blend),
    1 on the axis, 0 at and beyond half ``spot_size_deg`` from it."""
    cos_half = np.cos(np.radians(min(float(spot_size_deg), 180.0)) / 2)
    width = max((1.0 - cos_half) * float(blend), 1e-8)
    t = np.clip((np.asarray(cos_axis, dtype=np.float64) - cos_half) / width, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def irradiance(points: np.ndarray, normals: np.ndarray, light: Light, T_world_cam: np.ndarray) -> np.ndarray:
    """Relative irradiance (N,) of the light ``light`` on the left eye at ``T_world_cam`` (OpenCV frame) at
    ``points`` with unit ``normals`` (oriented to the light's side): sum over outlets of
    spot * max(cos incidence, 0) / r^2 (the spot pointing down the camera's +z; a point light has no cone)."""
    R, t = np.asarray(T_world_cam, float)[:3, :3], np.asarray(T_world_cam, float)[:3, 3]
    axis = R[:, 2]
    total = np.zeros(len(points))
    for offset in light.outlet_offsets():
        to_light = (R @ np.asarray(offset, float) + t) - points
        r2 = np.maximum(np.einsum("ij,ij->i", to_light, to_light), 1e-12)
        unit = to_light / np.sqrt(r2)[:, None]
        cos_in = np.maximum(np.einsum("ij,ij->i", normals, unit), 0.0)
        cone = spot_mask(-unit @ axis, light.spot_size_deg) if light.kind == "spot" else 1.0
        total += cone * cos_in / r2
    return total


def texel_indices(uvs: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of the texel whose centre each UV is (u = (col+0.5)/W, v = 1-(row+0.5)/H)."""
    cols = np.clip(np.rint(uvs[:, 0] * width - 0.5).astype(np.int64), 0, width - 1)
    rows = np.clip(np.rint((1.0 - uvs[:, 1]) * height - 0.5).astype(np.int64), 0, height - 1)
    return rows, cols


def delight_texture(texture: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, uvs: np.ndarray,
                    light: Light, T_world_cam: np.ndarray | None = None,
                    max_gain: float = MAX_GAIN, smooth_px: float = 0.0) -> tuple[np.ndarray, dict]:
    """The albedo texture (uint8 RGB, the texture's shape) of a texture lit by ``light`` at ``T_world_cam``, and
    statistics for scene.json. See the module docstring for the method, the level and the clamp.

    Parameters
    ----------
    texture : uint8 (H, W, 3), sRGB
        The capture image the mesh is textured with.
    vertices, triangles, uvs : the mesh (world frame, metres) and each vertex's texel centre.
    light : the scope light as the render builds it.
    T_world_cam : the capture camera (left eye, OpenCV frame); None: the world frame (CONVENTIONS 1.2).
    max_gain : the largest gain applied to a texel.
    smooth_px : Gaussian sigma (texels) of the shading map, over the meshed texels only; 0: per vertex.
    """
    h, w = texture.shape[:2]
    T_world_cam = np.eye(4) if T_world_cam is None else np.asarray(T_world_cam, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64)
    normals = vertex_normals(v, triangles, "angle")
    used = np.linalg.norm(normals, axis=1) > 0
    # the grid mesh faces the capture camera; orient every normal to the camera's side all the same
    eye = np.asarray(T_world_cam, float)[:3, 3]
    flip = np.einsum("ij,ij->i", normals, eye - v) < 0
    normals[flip] *= -1.0
    E = irradiance(v[used], normals[used], light, T_world_cam)
    rows, cols = texel_indices(np.asarray(uvs)[used], w, h)
    if smooth_px > 0:
        E_map, mask = np.zeros((h, w)), np.zeros((h, w))
        E_map[rows, cols], mask[rows, cols] = E, 1.0
        weight = np.maximum(ndi.gaussian_filter(mask, smooth_px), 1e-12)
        E = (ndi.gaussian_filter(E_map, smooth_px) / weight)[rows, cols]
    linear = srgb_decode(np.asarray(texture, dtype=np.float64) / 255.0)
    seen = linear[rows, cols]
    E_ref = float(np.median(E[E > 0])) if np.any(E > 0) else 1.0  # texels the light reaches
    gain = E_ref / np.maximum(E, E_ref / max_gain)
    gain_map = np.full((h, w), np.nan)
    gain_map[rows, cols] = gain
    missing = np.isnan(gain_map)
    if missing.any() and not missing.all():
        nearest = ndi.distance_transform_edt(missing, return_distances=False, return_indices=True)
        gain_map = gain_map[tuple(nearest)]
    albedo = linear * np.nan_to_num(gain_map, nan=1.0)[..., None]
    clipped = albedo[rows, cols].max(axis=1) > 1.0
    out = np.clip(np.rint(srgb_encode(albedo) * 255.0), 0, 255).astype(np.uint8)
    level = float(np.mean(np.minimum(albedo[rows, cols], 1.0)) / max(float(np.mean(seen)), 1e-12))
    stats = {"texels": int(len(rows)), "mean_level_ratio": round(level, 4),
             "gain_percentiles_5_50_95": np.percentile(gain, [5, 50, 95]).round(4).tolist(),
             "clamped_share": round(float(np.mean(E < E_ref / max_gain)), 5),
             "clipped_share": round(float(np.mean(clipped)), 5)}
    return out, stats
