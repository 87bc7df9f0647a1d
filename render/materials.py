"""Material node graphs (Cycles), one function per material kind, behind :func:`make_material`.

Tissue looks:

* ``as_captured``: unlit, Emission strength 1 from the sRGB texture: rendered from the capture camera with
  the scene's Standard view transform, an 8-bit render gives back the texture bytes.
* ``wet_tissue``: glossy, light-dependent tissue (Principled BSDF with a thin wet coat and a little
  subsurface scattering), plus the procedural micro-structure of
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
#: Wet-tissue BSDF: roughness and a thin wet coat; metres for the subsurface scale (mm-scale scattering).
WET_TISSUE = {"Roughness": 0.3, "Specular IOR Level": 0.5, "IOR": 1.4,
              "Coat Weight": 0.3, "Coat Roughness": 0.08, "Coat IOR": 1.33,
              "Subsurface Weight": 0.05, "Subsurface Scale": 0.0005}


def make_material(material: Material, image=None, vertex_colors: bool = True):
    """The Blender material of a part's :class:`~rgbd2scene.scene.model.Material`, coloured by ``image`` (its
    texture) or, without one, the mesh's vertex colours (when ``vertex_colors``) or the material's colour."""
    if material.kind == "as_captured":
        return as_captured_material(image)
    if material.kind == "wet_tissue":
        return wet_tissue_material(image, material.detail)
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


def wet_tissue_material(image=None, detail: TissueDetail | None = None):
    """Glossy tissue lit by the scope light, with the procedural micro-structure when ``detail`` is given and
    enabled."""
    mat, nodes, links = _new_material("wet_tissue")
    colour = _colour_source(nodes, image)
    shader = nodes.new("ShaderNodeBsdfPrincipled")
    links.new(colour, shader.inputs["Subsurface Radius"])  # reddish scattering, from the capture's colour
    if detail is not None and detail.enabled:
        colour, normal = add_tissue_detail(nodes, links, colour, detail)
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
    result = _mix_colour(nodes, links, "MULTIPLY", 1.0, colour, tint)
    result = _mix_colour(nodes, links, "MULTIPLY", 1.0, result, modulation)

    bumps = _noise(nodes, links, position, detail.scale_m, detail=6.0, roughness=0.6, w=1.0)
    height = _math(nodes, links, "MULTIPLY_ADD", vessels, VESSEL_RELIEF, bumps)
    bump = nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 1.0
    bump.inputs["Distance"].default_value = detail.bump_height_m
    links.new(height, bump.inputs["Height"])
    return result, bump.outputs["Normal"]


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
