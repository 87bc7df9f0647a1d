"""A scene part's mesh as arrays, cached in the scene folder (``.cache/``) for the processes that compute the
ground truth: parsing the bundled sample's 307k-vertex PLY takes about 0.15 s of CPU per process (every
render worker, ``render --gt-only``, ``verify``), loading its arrays about 0.01 s.

A cache file is named after the mesh file and its identity on disk (size, modification time in ns, inode): a
mesh written again (scenes are written atomically: a new inode) is read again, and the stale file replaced.
The cache is an optimisation only: an unreadable cache file is ignored, an unwritable folder skipped.
"""

from __future__ import annotations

import contextlib
import zipfile
from pathlib import Path

import numpy as np

from rgbd2scene.files.atomic import atomic_path
from rgbd2scene.files.meshio import read_ply

#: The cache folder, inside the scene folder.
CACHE_DIR = ".cache"


def _cache_path(mesh_path: Path) -> Path:
    st = mesh_path.stat()
    return mesh_path.parent / CACHE_DIR / f"{mesh_path.name}.{st.st_size:x}-{st.st_mtime_ns:x}-{st.st_ino:x}.npz"


def mesh_arrays(mesh_path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float32 as the PLY stores them, triangles (M, 3) int32) of a PLY mesh, from the cache
    when it holds this version of the file (else read, then cached)."""
    mesh_path = Path(mesh_path)
    if not mesh_path.is_file():
        return _arrays_of(mesh_path)  # read_ply's error
    cache = _cache_path(mesh_path)
    with contextlib.suppress(OSError, ValueError, KeyError, zipfile.BadZipFile), np.load(cache) as stored:
        return stored["vertices"], stored["triangles"]
    vertices, triangles = _arrays_of(mesh_path)
    with contextlib.suppress(OSError):
        for stale in cache.parent.glob(f"{mesh_path.name}.*.npz"):
            stale.unlink(missing_ok=True)
        with atomic_path(cache) as tmp:
            np.savez(tmp, vertices=vertices, triangles=triangles)
    return vertices, triangles


def _arrays_of(mesh_path: Path) -> tuple[np.ndarray, np.ndarray]:
    mesh = read_ply(mesh_path)
    return mesh.vertices.astype(np.float32), np.asarray(mesh.triangles, dtype=np.int32)
