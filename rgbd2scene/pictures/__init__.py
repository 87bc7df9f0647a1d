"""Pictures people look at: capture overview, dataset contact sheet, Open3D preview.

The names below load their module on first use (:mod:`rgbd2scene.lazy`): the mesh stage draws the overview
only."""

from rgbd2scene.lazy import lazy_names

_SUBMODULE_OF = {"write_overview": "overview", "write_frame_sheet": "contact_sheet", "preview": "mesh_preview"}

__all__ = sorted(_SUBMODULE_OF)
__getattr__, __dir__ = lazy_names(__name__, _SUBMODULE_OF)
