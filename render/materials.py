"""Material node graphs of objects (Cycles): one function per material kind, registered in ``OBJECT_MATERIALS``.

Each function takes the part's :class:`~rgbd2scene.scene.model.Material`, the Blender image of its texture
(or None) and whether its mesh has vertex colours, and returns a new material. The colour is the texture's
(through the mesh's UVs) if there is one, else ``Material.color`` (linear RGB) if given, else the vertex
colours (attribute ``Col``) if the mesh has them, else the kind's own colour.

* ``metal``: Principled BSDF, fully metallic, low roughness, brushed (anisotropic, the tangent running
  around the part's z axis: the shaft's and the jaws' length);
* ``dark_plastic``: near-black dielectric with a soft sheen (an insulated instrument shaft);
* ``color``: plain Principled BSDF in the part's colour.

None of them reaches the ground truth: the data render overrides every material with black emission.
"""

from __future__ import annotations

import bpy

from rgbd2scene.scene.model import Material

VERTEX_COLORS = "Col"
STEEL = (0.8, 0.8, 0.82)  # linear RGB base colour of stainless steel
DARK_PLASTIC = (0.012, 0.012, 0.014)
PLAIN = (0.5, 0.5, 0.5)


def _new(name: str):
    mat = bpy.data.materials.new(name)
    nodes = mat.node_tree.nodes
    nodes.clear()
    return mat, nodes, mat.node_tree.links, nodes.new("ShaderNodeOutputMaterial")


def _principled(nodes, links, out, material: Material, image, vertex_colors: bool, default_colour, settings: dict):
    shader = nodes.new("ShaderNodeBsdfPrincipled")
    if image is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        tex.interpolation = "Linear"
        links.new(tex.outputs["Color"], shader.inputs["Base Color"])
    elif material.color is None and vertex_colors:
        colour = nodes.new("ShaderNodeVertexColor")
        colour.layer_name = VERTEX_COLORS
        links.new(colour.outputs["Color"], shader.inputs["Base Color"])
    else:
        shader.inputs["Base Color"].default_value = (*(material.color or default_colour), 1.0)
    for key, value in settings.items():
        shader.inputs[key].default_value = value
    links.new(shader.outputs["BSDF"], out.inputs["Surface"])
    return shader


def metal_material(material: Material, image=None, vertex_colors: bool = False):
    """Brushed stainless steel."""
    mat, nodes, links, out = _new("metal")
    shader = _principled(nodes, links, out, material, image, vertex_colors, STEEL,
                         {"Metallic": 1.0, "Roughness": 0.3, "Anisotropic": 0.6})
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "RADIAL"
    tangent.axis = "Z"
    links.new(tangent.outputs["Tangent"], shader.inputs["Tangent"])
    return mat


def dark_plastic_material(material: Material, image=None, vertex_colors: bool = False):
    """Near-black insulation with a soft specular sheen."""
    mat, nodes, links, out = _new("dark_plastic")
    _principled(nodes, links, out, material, image, vertex_colors, DARK_PLASTIC,
                {"Metallic": 0.0, "Roughness": 0.35, "Specular IOR Level": 0.5, "Coat Weight": 0.2,
                 "Coat Roughness": 0.1})
    return mat


def color_material(material: Material, image=None, vertex_colors: bool = False):
    """A plain dielectric in the part's colour (texture, ``Material.color`` or vertex colours)."""
    mat, nodes, links, out = _new("color")
    _principled(nodes, links, out, material, image, vertex_colors, PLAIN, {"Roughness": 0.5})
    return mat


#: Material kind (``Material.kind``) -> the function that builds it.
OBJECT_MATERIALS = {"metal": metal_material, "dark_plastic": dark_plastic_material, "color": color_material}
