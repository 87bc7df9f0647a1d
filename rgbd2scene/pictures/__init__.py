"""Pictures people look at: capture overview, dataset contact sheet, Open3D preview."""

from rgbd2scene.pictures.contact_sheet import write_frame_sheet
from rgbd2scene.pictures.overview import write_overview
from rgbd2scene.pictures.preview import preview

__all__ = ["preview", "write_frame_sheet", "write_overview"]
