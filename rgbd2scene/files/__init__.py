"""Files other tools read: atomic writes, PLY and textured OBJ meshes."""

from rgbd2scene.files.atomic import atomic_path, ensure_output_dir, write_bytes, write_json, write_npy, write_text
from rgbd2scene.files.meshio import read_ply, write_ply, write_textured_obj

__all__ = ["atomic_path", "ensure_output_dir", "read_ply", "write_bytes", "write_json", "write_npy", "write_ply",
    "write_text", "write_textured_obj"]
