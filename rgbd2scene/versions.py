"""Versions of the software that made a scene or dataset (recorded for provenance)."""

from __future__ import annotations

import functools
import platform
from importlib import metadata

from rgbd2scene import __version__


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def software_versions() -> dict:
    """Versions from package metadata (nothing is imported), looked up once per process: each package's is a
    scan of the import path (10 ms for the seven)."""
    return dict(_software_versions())


@functools.cache
def _software_versions() -> dict:
    return {"rgbd2scene": __version__, "python": platform.python_version(), "bpy": _version("bpy"),
            "numpy": _version("numpy"), "open3d": _version("open3d"),
            "opencv": _version("opencv-contrib-python-headless") or _version("opencv-python-headless")
            or _version("opencv-python"), "OpenEXR": _version("OpenEXR")}
