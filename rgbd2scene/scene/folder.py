"""File names of a scene folder (CONVENTIONS §4): the one place that spells them.

```
SCENE/scene.json          the record (written last: a folder with it is complete)
SCENE/scene.blend         the Blender scene
SCENE/mesh.ply            the tissue surface (binary PLY, vertex colours, UVs, metres, world frame)
SCENE/depth_filled.npy    the capture depth the mesh was built from
SCENE/mesh.obj/.mtl, mesh_texture.png, texture_original.png, texture_lit.png, overview.png
SCENE/objects/<id>.ply    each rigid object part, in its own frame (and <id>_texture.png if textured)
```
"""

SCENE_JSON = "scene.json"
SCENE_BLEND = "scene.blend"
MESH = "mesh.ply"
DEPTH_FILLED = "depth_filled.npy"
MESH_NAME = "mesh"  # mesh.obj, mesh.mtl and mesh_texture.png
TEXTURED_MESH = f"{MESH_NAME}.obj"
MATERIAL_LIBRARY = f"{MESH_NAME}.mtl"
TEXTURE = f"{MESH_NAME}_texture.png"
TEXTURE_ORIGINAL = "texture_original.png"  # the capture image as captured, when highlights were removed
TEXTURE_LIT = "texture_lit.png"  # the texture before the capture light was divided out (scene stage, --delight)
OVERVIEW = "overview.png"
OBJECTS_DIR = "objects"
#: What a mesh folder (``rgbd2scene mesh``) holds besides scene.json; copied when a scene reuses one.
MESH_FOLDER_FILES = (MESH, DEPTH_FILLED, TEXTURED_MESH, MATERIAL_LIBRARY, TEXTURE, TEXTURE_ORIGINAL, OVERVIEW)


def object_geometry(part_id: int) -> str:
    """Scene-folder path of the geometry of the object part with instance id ``part_id``."""
    return f"{OBJECTS_DIR}/{int(part_id)}.ply"


def object_texture(part_id: int) -> str:
    """Scene-folder path of the texture image of the object part ``part_id`` (mapped by its PLY's UVs)."""
    return f"{OBJECTS_DIR}/{int(part_id)}_texture.png"
