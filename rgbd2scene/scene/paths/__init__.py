"""Camera paths and object tracks: per-frame poses T_world_X, made from waypoints or drawn over the mesh.

- ``track``: :class:`Track` (poses of any object, ``pose_at(frame)``, ``to_dict``/``from_dict``) and
  :class:`CameraPath`, the camera's track (left-eye ``T_world_cam``); ``look_at``.
- ``waypoints``: splines through waypoints and path files, for the camera or any object's track.
- ``surface``: the mesh as seen along the capture direction, view footprints, placement at a standoff,
  and ``path_coverage``.
- ``generators``: one function per generated kind, registered in ``PATH_GENERATORS``.
- ``make``: ``make_path``, the driver (checks, growing footprint allowance, coverage check, settings).

Adding a path kind is one function and one registry line: write ``def spiral_path(ctx, rng, *, option=default)
-> Placement | None`` in ``generators.py`` (see its module docstring for the contract) and add
``"spiral": spiral_path`` to ``PATH_GENERATORS``; ``make_path``, ``PATH_KINDS`` and the CLI's ``--path``
choices follow from the registry.
"""

from rgbd2scene.scene.paths.generators import PATH_GENERATORS, PathContext, Placement
from rgbd2scene.scene.paths.make import DEFAULT_SPEED, DEFAULT_STANDOFF, PATH_KINDS, make_path
from rgbd2scene.scene.paths.surface import path_coverage
from rgbd2scene.scene.paths.track import CameraPath, Track, look_at
from rgbd2scene.scene.paths.waypoints import load_path_file, save_path_file, waypoint_path

__all__ = ["CameraPath", "DEFAULT_SPEED", "DEFAULT_STANDOFF", "PATH_GENERATORS", "PATH_KINDS", "PathContext",
           "Placement", "Track", "load_path_file", "look_at", "make_path", "path_coverage", "save_path_file",
           "waypoint_path"]
