"""Material node graphs (Cycles), one function per material kind, behind :func:`make_material`.

Tissue looks:

* ``as_captured``: unlit, Emission strength 1 from the sRGB texture: rendered from the capture camera with
  the scene's Standard view transform, an 8-bit render gives back the texture bytes.
* ``wet_tissue``: glossy, light-dependent tissue (Principled BSDF with a thin wet coat), plus the procedural
  micro-structure of
  :class:`~rgbd2scene.scene.materials.TissueDetail` when it is enabled.

The micro-structure (:func:`add_tissue_detail`) works in metres on the tissue surface: the "Generated"
texture coordinates of the undeformed mesh, made metric by :func:`use_metric_texture_space` (texture space
centred at the origin, 1 m wide: Generated = position + 0.5 m), so the pattern sticks to the surface if it
ever deforms and keeps its physical size at any camera distance. It has three layers:

1. **Mottling**: fractal noise n (4 octaves from ``scale_m`` down) multiplies the colour by
   ``1 + mottle_strength * (n - 0.5) / MOTTLE_NOISE_STD``: mean 1 (the capture's colour survives at low
   spatial frequencies), relative standard deviation ``mottle_strength``.
2. **Vessels**: thin meandering lines ``vessel_width_m`` wide (where a smooth noise of period
   ``vessel_spacing_m`` crosses its mean), in patches (a coarser noise switches them on over about half
   the surface), pull the colour towards dark red (``VESSEL_TINT``) by ``vessel_strength`` at their
   centre line. The colour is then divided by the mean darkening (``VESSEL_COVERAGE_PER_WIDTH``,
   measured), so the mean colour stays the capture's.
3. **Bumps**: fractal noise (6 octaves from ``scale_m`` down) plus the vessels, raised by 0.3 of it, as a
   height of ``bump_height_m`` through a Bump node into the BSDF's and the coat's normals: shading only,
   the mesh does not move.

Evaluated per shading sample, those noises (some 30 octaves of 4-D Perlin noise, the bump's height three
times) cost as much as the rest of a sample. When the scene is built they are therefore **baked**
(:func:`bake_tissue_detail`, ``TissueDetail.bake``) into two float textures over the mesh's UVs: the colour
multiplier (mottling x vessels) and the height, at the texel size the closest camera position needs
(:func:`detail_texture_size`); the material then reads them like the capture's texture. Detail finer than a
texel is averaged (several samples per texel), as a pixel would average it. A mesh without usable UVs keeps
the procedural nodes.

Object looks (:data:`OBJECT_MATERIALS`; colour from the texture, else ``Material.color``, else the vertex
colours, else the kind's own):

* ``metal``: Principled BSDF, fully metallic, low roughness, brushed (anisotropic, the tangent running
  around the part's z axis: the shaft's and the jaws' length);
* ``dark_plastic``: near-black dielectric with a soft sheen (an insulated instrument shaft);
* ``color``: plain Principled BSDF in the part's colour.

None of it reaches the ground truth: the data render overrides every material with black emission, and
the Normal pass is then the mesh's interpolated normal.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from rgbd2scene.scene.materials import MOTTLE_NOISE_STD, TissueDetail
from rgbd2scene.scene.model import Material

VERTEX_COLORS = "Col"
#: Texture filtering: bilinear. At texel centres (the capture view) it is as exact as 'Closest'
#: (round-trip test) and it does not turn magnified tissue into blocks when the scope moves closer.
TEXTURE_INTERPOLATION = "Linear"
#: Colour at a vessel's centre line relative to the tissue's (linear RGB): dark red, blood under a thin wall.
VESSEL_TINT = (0.55, 0.18, 0.22)
#: Typical growth of |n - 0.5| per noise period across a crossing of Blender's (smooth, 1-octave) noise, and
#: the mean of (vessel line x patch mask) over the surface per unit of vessel_width_m / vessel_spacing_m:
#: both measured on rendered planes (vessel full width at half maximum; mean colour). tests/test_materials.py
#: checks that the mean colour holds.
NOISE_CROSSING_SLOPE = 0.58
VESSEL_COVERAGE_PER_WIDTH = 0.65
#: Height of the vessels relative to the bumps' (slightly raised: superficial vessels bulge a little).
VESSEL_RELIEF = 0.3
#: Range of the seed-derived offset of the pattern coordinates, in metres.
SEED_OFFSET_M = 1.0
#: Wet-tissue BSDF: roughness and a thin wet coat. No subsurface scattering: the 5 % random-walk layer of 0.5 mm
#: it had was most of a sample's noise (16 samples: 35.6 dB against 256, 39.0 dB without it) and cost 15 % of the
#: path tracing, while the converged images with and without it differ by about 53 dB, far below the renders'
#: own error (benchmarks/results/render.md, section 8).
WET_TISSUE = {"Roughness": 0.3, "Specular IOR Level": 0.5, "IOR": 1.4,
              "Coat Weight": 0.3, "Coat Roughness": 0.08, "Coat IOR": 1.33}


def make_material(material: Material, image=None, vertex_colors: bool = True, baked: tuple | None = None):
    """The Blender material of a part's :class:`~rgbd2scene.scene.model.Material`, coloured by ``image`` (its
    texture) or, without one, the mesh's vertex colours (when ``vertex_colors``) or the material's colour;
    ``baked``: the wet-tissue detail's images (:func:`bake_tissue_detail`)."""
    if material.kind == "as_captured":
        return as_captured_material(image)
    if material.kind == "wet_tissue":
        return wet_tissue_material(image, material.detail, baked)
    if material.kind in OBJECT_MATERIALS:
        return OBJECT_MATERIALS[material.kind](material, image, vertex_colors)
    raise ValueError(f"unknown material {material.kind!r}; choose one of as_captured, wet_tissue, "
                     f"{', '.join(OBJECT_MATERIALS)}")


def as_captured_material(image=None):
    """Unlit: Emission strength 1 of the texture's (or vertex colours') colour."""
    mat, nodes, links = _new_material("as_captured")
    shader = nodes.new("ShaderNodeEmission")
    shader.inputs["Strength"].default_value = 1.0
    links.new(_colour_source(nodes, image), shader.inputs["Color"])
    links.new(shader.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    return mat


def wet_tissue_material(image=None, detail: TissueDetail | None = None, baked: tuple | None = None):
    """Glossy tissue lit by the scope light, with the micro-structure when ``detail`` is given and enabled:
    procedural, or read from ``baked`` (the multiplier and height images of :func:`bake_tissue_detail`)."""
    mat, nodes, links = _new_material("wet_tissue")
    colour = _colour_source(nodes, image)
    shader = nodes.new("ShaderNodeBsdfPrincipled")
    if detail is not None and detail.enabled:
        if baked is None:
            colour, normal = add_tissue_detail(nodes, links, colour, detail)
        else:
            multiplier, height = (_baked_source(nodes, links, img) for img in baked)
            colour, normal = _apply_detail(nodes, links, colour, multiplier, height, detail)
        links.new(normal, shader.inputs["Normal"])
        links.new(normal, shader.inputs["Coat Normal"])  # the wet film follows the surface
    links.new(colour, shader.inputs["Base Color"])
    for key, value in WET_TISSUE.items():
        shader.inputs[key].default_value = value
    links.new(shader.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])
    return mat


def use_metric_texture_space(mesh) -> None:
    """Make the mesh's Generated coordinates metric: position + 0.5 m (undeformed mesh, object frame)."""
    mesh.use_auto_texspace = False
    mesh.texspace_location = (0.0, 0.0, 0.0)
    mesh.texspace_size = (0.5, 0.5, 0.5)  # half-sizes: a 1 m box around the origin


def add_tissue_detail(nodes, links, colour, detail: TissueDetail):
    """Mottling, vessels and bumps (see the module docstring) on the colour socket ``colour``.

    Returns the sockets of the new base colour and of the bumped normal.
    """
    multiplier, height = detail_fields(nodes, links, detail)
    return _apply_detail(nodes, links, colour, multiplier, height, detail)


def _apply_detail(nodes, links, colour, multiplier, height, detail: TissueDetail):
    """The base colour (``colour`` x the detail's ``multiplier``) and the normal bumped by ``height``."""
    result = _mix_colour(nodes, links, "MULTIPLY", 1.0, colour, multiplier)
    bump = nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 1.0
    bump.inputs["Distance"].default_value = detail.bump_height_m
    links.new(height, bump.inputs["Height"])
    return result, bump.outputs["Normal"]


def detail_fields(nodes, links, detail: TissueDetail):
    """The procedural detail as two fields over the surface: the colour multiplier (mean 1: mottling and
    vessels) and the height (bumps plus raised vessels, in units of ``bump_height_m``); their sockets."""
    coords = nodes.new("ShaderNodeTexCoord")
    offset = nodes.new("ShaderNodeVectorMath")
    offset.operation = "ADD"
    offset.inputs[1].default_value = _seed_offset(detail.seed)
    links.new(coords.outputs["Generated"], offset.inputs[0])
    position = offset.outputs["Vector"]  # metres (+ the seed's offset)

    mottle = _noise(nodes, links, position, detail.scale_m, detail=4.0)
    spread = detail.mottle_strength / MOTTLE_NOISE_STD  # 1 + mottle_strength x (n - 0.5) / std(n)
    modulation = _map_range(nodes, links, mottle, 0.0, 1.0, 1.0 - 0.5 * spread, 1.0 + 0.5 * spread)
    vessels = _vessels(nodes, links, position, detail)

    # white -> vessel tint by vessel_strength x vessel, divided by the mean darkening (mean colour kept)
    strength = _math(nodes, links, "MULTIPLY", vessels, detail.vessel_strength)
    tint = _mix_colour(nodes, links, "MIX", strength, (1.0, 1.0, 1.0), VESSEL_TINT)
    coverage = VESSEL_COVERAGE_PER_WIDTH * detail.vessel_width_m / detail.vessel_spacing_m
    mean = [1.0 - detail.vessel_strength * coverage * (1.0 - t) for t in VESSEL_TINT]
    tint = _mix_colour(nodes, links, "MULTIPLY", 1.0, tint, [1.0 / m for m in mean])
    multiplier = _mix_colour(nodes, links, "MULTIPLY", 1.0, tint, modulation)

    bumps = _noise(nodes, links, position, detail.scale_m, detail=6.0, roughness=0.6, w=1.0)
    height = _math(nodes, links, "MULTIPLY_ADD", vessels, VESSEL_RELIEF, bumps)
    return multiplier, height


# --- baking the detail ------------------------------------------------------------------------------------

#: Texels of the baked detail across one pixel of the closest view (bilinear lookups then keep about a
#: pixel's worth of detail), the largest side of a baked texture, and the bake's samples per texel (they
#: average the detail finer than a texel).
BAKE_TEXELS_PER_PIXEL = 1.0
BAKE_MAX_SIZE = 4096
BAKE_SAMPLES = 1
#: The baked textures are 16-bit PNGs of value / BAKE_RANGE (the multiplier reaches about 1.3, the height 1.3).
BAKE_RANGE = 2.0
#: The UV map the baked textures are read through: the seen part of the capture's UV square, stretched to
#: [0, 1]^2 (the bake fills the whole image, so only what the path can see is baked).
DETAIL_UV = "DetailUV"
#: Extra margin of the seen UV window, as a fraction of its size on each side.
WINDOW_MARGIN = 0.02
#: Below this UV area per unit of surface area (a UV map that does not unfold the mesh) nothing is baked.
MIN_UV_DENSITY = 1e-6


def seen_vertices(vertices, poses, K, width: int, height: int, margin: float = 0.1) -> tuple[np.ndarray, float]:
    """Which vertices some camera of the path sees (in front of it, inside the image widened by ``margin``
    of its size on each side; occlusion ignored), and the closest distance along a viewing axis among them.

    ``poses``: (F, 4, 4) T_world_cam (OpenCV axes) in the vertices' frame; ``K``: 3x3 intrinsics.
    """
    v = np.asarray(vertices, np.float64)
    seen = np.zeros(len(v), bool)
    closest = np.inf
    for T in np.asarray(poses, np.float64):
        R, t = T[:3, :3], T[:3, 3]
        d = v - t
        x, y, z = (d @ R[:, 0], d @ R[:, 1], d @ R[:, 2])  # camera coordinates, written out (faster)
        front = z > 1e-9
        zs = np.where(front, z, 1.0)
        u, w = K[0, 0] * x / zs + K[0, 2], K[1, 1] * y / zs + K[1, 2]
        inside = front & (np.abs(u - (width - 1) / 2) <= width * (0.5 + margin)) & \
            (np.abs(w - (height - 1) / 2) <= height * (0.5 + margin))
        if inside.any():
            seen |= inside
            closest = min(closest, float(z[inside].min()))
    return seen, closest


def detail_uv_window(uvs, seen) -> tuple[np.ndarray, np.ndarray] | None:
    """The UV box (lower corner, upper corner) of the seen vertices, widened by ``WINDOW_MARGIN``; None if
    nothing is seen."""
    uv = np.asarray(uvs, np.float64)[np.asarray(seen, bool)]
    if len(uv) == 0:
        return None
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    pad = WINDOW_MARGIN * np.maximum(hi - lo, 1e-6)
    return lo - pad, hi + pad


def detail_texture_size(vertices, triangles, uvs, window, closest: float, fx: float,
                        texels_per_pixel: float = BAKE_TEXELS_PER_PIXEL,
                        max_size: int = BAKE_MAX_SIZE) -> tuple[int, int] | None:
    """(width, height) of a texture over the UV ``window`` whose texels are ``texels_per_pixel`` times finer
    than a pixel at the ``closest`` distance (metres) of a camera of focal length ``fx`` pixels, or None when
    the UVs do not unfold the mesh.

    The metres per UV unit along u and along v are the medians over the triangles of the columns of the
    Jacobian d(position)/d(uv). The texture keeps its aspect when ``max_size`` caps it.
    """
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    uv = np.asarray(uvs, np.float64)
    e = np.stack([v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]], axis=-1)  # (T, 3, 2)
    d = np.stack([uv[t[:, 1]] - uv[t[:, 0]], uv[t[:, 2]] - uv[t[:, 0]]], axis=-1)  # (T, 2, 2)
    det = d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0]
    area = 0.5 * np.linalg.norm(np.cross(e[..., 0], e[..., 1]), axis=-1)
    ok = np.abs(det) > MIN_UV_DENSITY * np.maximum(area, 1e-30)
    if ok.sum() < max(1, len(t) // 10):
        return None
    inv = np.stack([np.stack([d[ok, 1, 1], -d[ok, 0, 1]], -1), np.stack([-d[ok, 1, 0], d[ok, 0, 0]], -1)], 1)
    jac = np.einsum("tij,tjk->tik", e[ok], inv / det[ok, None, None])  # d(position) / d(u, v)
    metres = np.median(np.linalg.norm(jac, axis=1), axis=0) * (np.asarray(window[1]) - np.asarray(window[0]))
    texel = max(float(closest), 1e-6) / float(fx) / texels_per_pixel
    size = metres / texel
    size *= min(1.0, max_size / size.max())
    size = np.ceil(size * (1 - 1e-5))  # not one texel more for a rounding error (float32 UVs)
    return int(max(2, size[0])), int(max(2, size[1]))


def bake_tissue_detail(obj, detail: TissueDetail, size: tuple[int, int], window,
                       samples: int = BAKE_SAMPLES) -> tuple:
    """Bake the procedural detail of ``detail`` on ``obj`` (its metric texture space) into two images of
    ``size`` (width, height) over the UV ``window`` of its UV map: the colour multiplier and the height.

    The window becomes the UV map :data:`DETAIL_UV` (stretched to the unit square); Cycles bakes each field as
    an emission (``EMIT``, ``samples`` per texel); the images are stored as 16-bit PNGs of value /
    :data:`BAKE_RANGE`, packed into the .blend. The scene's render settings are put back afterwards.
    """
    import tempfile

    from rgbd2scene.files.images import write_image

    scene, layers = bpy.context.scene, obj.data.uv_layers
    source = layers.active
    uv = np.empty(2 * len(obj.data.loops), np.float32)
    source.uv.foreach_get("vector", uv)
    lo, hi = (np.asarray(c, np.float32) for c in window)
    detail_uv = layers.new(name=DETAIL_UV)
    detail_uv.uv.foreach_set("vector", ((uv.reshape(-1, 2) - lo) / (hi - lo)).ravel())
    source.active_render = True  # the capture's texture stays on the capture's UVs

    mat, nodes, links = _new_material("tissue_detail_bake")
    multiplier, height = detail_fields(nodes, links, detail)
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0 / BAKE_RANGE
    links.new(emission.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    target = nodes.new("ShaderNodeTexImage")
    nodes.active = target
    kept_materials = list(obj.data.materials)
    saved = (scene.render.engine, scene.cycles.samples, scene.cycles.use_denoising,
             bpy.context.view_layer.objects.active)
    images = []
    try:
        obj.data.materials.clear()
        obj.data.materials.append(mat)
        layers.active = detail_uv  # the bake writes through the active UV map
        scene.render.engine = "CYCLES"
        scene.cycles.samples, scene.cycles.use_denoising = int(samples), False
        for o in bpy.context.view_layer.objects:
            o.select_set(o == obj)
        bpy.context.view_layer.objects.active = obj
        with tempfile.TemporaryDirectory(prefix="rgbd2scene-bake-") as tmp:
            for name, field in (("multiplier", multiplier), ("height", height)):
                work = bpy.data.images.new(f"bake_{name}", size[0], size[1], alpha=False, float_buffer=True)
                work.colorspace_settings.name = "Non-Color"  # before the pixels (see add_texture)
                links.new(field, emission.inputs["Color"])
                target.image = work
                bpy.ops.object.bake(type="EMIT", margin=4, margin_type="EXTEND", use_clear=True)
                pixels = np.empty(size[0] * size[1] * 4, np.float32)
                work.pixels.foreach_get(pixels)
                bpy.data.images.remove(work)
                rgb = pixels.reshape(size[1], size[0], 4)[::-1, :, :3]  # rows top first
                if name == "height":
                    rgb = rgb[..., 0]
                path = Path(tmp) / f"tissue_detail_{name}.png"
                write_image(path, np.round(np.clip(rgb, 0.0, 1.0) * 65535.0).astype(np.uint16), compression=9)
                image = bpy.data.images.load(str(path))
                image.colorspace_settings.name = "Non-Color"
                image.pack()
                image.filepath = f"//{path.name}"  # packed: the temporary file is not needed
                images.append(image)
    finally:
        layers.active = source
        obj.data.materials.clear()
        for m in kept_materials:
            obj.data.materials.append(m)
        scene.render.engine, scene.cycles.samples, scene.cycles.use_denoising = saved[:3]
        bpy.context.view_layer.objects.active = saved[3]
        bpy.data.materials.remove(mat)
    return tuple(images)


# --- helpers --------------------------------------------------------------------------------------------

def _new_material(name: str):
    mat = bpy.data.materials.new(name)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    nodes.new("ShaderNodeOutputMaterial")
    return mat, nodes, links


def _colour_source(nodes, image):
    """Colour socket of the capture: the image texture (bilinear, edges extended) or the vertex colours."""
    if image is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        tex.interpolation = TEXTURE_INTERPOLATION
        tex.extension = "EXTEND"
    else:
        tex = nodes.new("ShaderNodeVertexColor")
        tex.layer_name = VERTEX_COLORS
    return tex.outputs["Color"]


def _baked_source(nodes, links, image):
    """A baked detail image through :data:`DETAIL_UV` (bilinear, edges extended), back to its values (x
    :data:`BAKE_RANGE`), as a colour socket."""
    uv = nodes.new("ShaderNodeUVMap")
    uv.uv_map = DETAIL_UV
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = TEXTURE_INTERPOLATION
    tex.extension = "EXTEND"
    links.new(uv.outputs["UV"], tex.inputs["Vector"])
    return _mix_colour(nodes, links, "MULTIPLY", 1.0, tex.outputs["Color"], (BAKE_RANGE,) * 3)


def _seed_offset(seed: int) -> tuple[float, float, float]:
    """A seed-determined place in the noise field, metres (float32 still resolves 0.1 um there)."""
    return tuple(float(x) for x in np.random.default_rng(seed).uniform(-SEED_OFFSET_M, SEED_OFFSET_M, 3))


def _noise(nodes, links, position, size_m: float, detail: float, roughness: float = 0.5, w: float = 0.0):
    """Fractal (4-D Perlin) noise of feature size ``size_m`` metres in [0, 1], mean 0.5; ``w``: another slice."""
    noise = nodes.new("ShaderNodeTexNoise")
    noise.noise_dimensions = "4D"
    links.new(position, noise.inputs["Vector"])
    noise.inputs["W"].default_value = w
    noise.inputs["Scale"].default_value = 1.0 / size_m
    noise.inputs["Detail"].default_value = detail
    noise.inputs["Roughness"].default_value = roughness
    return noise.outputs["Factor"]


def _map_range(nodes, links, value, from_min, from_max, to_min, to_max, interpolation="LINEAR", clamp=False):
    node = nodes.new("ShaderNodeMapRange")
    node.interpolation_type, node.clamp = interpolation, clamp
    links.new(value, node.inputs["Value"])
    for key, v in (("From Min", from_min), ("From Max", from_max), ("To Min", to_min), ("To Max", to_max)):
        node.inputs[key].default_value = v
    return node.outputs["Result"]


def _math(nodes, links, operation: str, *operands):
    """A Math node; operands are sockets or numbers."""
    node = nodes.new("ShaderNodeMath")
    node.operation = operation
    for slot, operand in zip(node.inputs, operands, strict=False):
        if isinstance(operand, int | float):
            slot.default_value = operand
        else:
            links.new(operand, slot)
    return node.outputs["Value"]


def _mix_colour(nodes, links, blend: str, factor, a, b):
    """A colour Mix node (``blend``: MIX, MULTIPLY, ...); factor, a and b are sockets or constants."""
    node = nodes.new("ShaderNodeMix")
    node.data_type, node.blend_type = "RGBA", blend
    sockets = {s.identifier: s for s in node.inputs}
    for key, value in (("Factor_Float", factor), ("A_Color", a), ("B_Color", b)):
        if isinstance(value, int | float):
            sockets[key].default_value = value
        elif isinstance(value, tuple | list):
            sockets[key].default_value = (*value, 1.0)
        else:
            links.new(value, sockets[key])
    return next(s for s in node.outputs if s.identifier == "Result_Color")


def _vessels(nodes, links, position, detail: TissueDetail):
    """1 on a vessel's centre line, 0 between vessels: where a smooth noise crosses its mean, in patches."""
    field = _noise(nodes, links, position, detail.vessel_spacing_m, detail=0.0, w=2.0)
    distance = _math(nodes, links, "ABSOLUTE", _math(nodes, links, "SUBTRACT", field, 0.5))
    # the line fades out (smoothstep) over |n - 0.5| < half_width: its full width at half maximum is
    # vessel_width_m where |n - 0.5| grows by NOISE_CROSSING_SLOPE per noise period
    half_width = NOISE_CROSSING_SLOPE * detail.vessel_width_m / detail.vessel_spacing_m
    line = _map_range(nodes, links, distance, 0.0, half_width, 1.0, 0.0, "SMOOTHSTEP", clamp=True)
    patches = _noise(nodes, links, position, 3.0 * detail.vessel_spacing_m, detail=1.0, w=3.0)
    mask = _map_range(nodes, links, patches, 0.45, 0.6, 0.0, 1.0, "SMOOTHSTEP", clamp=True)
    return _math(nodes, links, "MULTIPLY", line, mask)


# --- object looks ----------------------------------------------------------------------------------

STEEL = (0.8, 0.8, 0.82)  # linear RGB base colour of stainless steel
DARK_PLASTIC = (0.012, 0.012, 0.014)
PLAIN = (0.5, 0.5, 0.5)


def _principled(nodes, links, material: Material, image, vertex_colors: bool, default_colour, settings: dict):
    shader = nodes.new("ShaderNodeBsdfPrincipled")
    if image is not None or (material.color is None and vertex_colors):
        links.new(_colour_source(nodes, image), shader.inputs["Base Color"])
    else:
        shader.inputs["Base Color"].default_value = (*(material.color or default_colour), 1.0)
    for key, value in settings.items():
        shader.inputs[key].default_value = value
    links.new(shader.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])
    return shader


def metal_material(material: Material, image=None, vertex_colors: bool = False):
    """Brushed stainless steel."""
    mat, nodes, links = _new_material("metal")
    shader = _principled(nodes, links, material, image, vertex_colors, STEEL,
                         {"Metallic": 1.0, "Roughness": 0.3, "Anisotropic": 0.6})
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "RADIAL"
    tangent.axis = "Z"
    links.new(tangent.outputs["Tangent"], shader.inputs["Tangent"])
    return mat


def dark_plastic_material(material: Material, image=None, vertex_colors: bool = False):
    """Near-black insulation with a soft specular sheen."""
    mat, nodes, links = _new_material("dark_plastic")
    _principled(nodes, links, material, image, vertex_colors, DARK_PLASTIC,
                {"Metallic": 0.0, "Roughness": 0.35, "Specular IOR Level": 0.5, "Coat Weight": 0.2,
                 "Coat Roughness": 0.1})
    return mat


def color_material(material: Material, image=None, vertex_colors: bool = False):
    """A plain dielectric in the part's colour (texture, ``Material.color`` or vertex colours)."""
    mat, nodes, links = _new_material("color")
    _principled(nodes, links, material, image, vertex_colors, PLAIN, {"Roughness": 0.5})
    return mat


#: Material kind (``Material.kind``) -> the function that builds it.
OBJECT_MATERIALS = {"metal": metal_material, "dark_plastic": dark_plastic_material, "color": color_material}
