"""How close rendered frames are to real ones (``rgbd2scene realism``, CONVENTIONS section 5).

- :mod:`~rgbd2scene.realism.measures`: image statistics (brightness, contrast, colour, noise, sharpness,
  highlights) on RGB arrays with an optional mask.
- :mod:`~rgbd2scene.realism.stereo`: stereo difficulty of a pair (SGBM and ELAS density, left-right
  consistency, error against the pair's own ground truth).
- :mod:`~rgbd2scene.realism.report`: the comparison of a dataset frame with a real frame or pair, its table.
- :mod:`~rgbd2scene.realism.picture`: the side-by-side picture.

:func:`run_realism` does it all and writes ``realism.md``, ``realism.json`` and ``realism.png``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rgbd2scene.realism.report import METHODS, RealismReport, compare, load_inputs, markdown_report

__all__ = ["METHODS", "RealismOutput", "RealismReport", "run_realism"]


@dataclass(frozen=True)
class RealismOutput:
    report: RealismReport
    markdown: Path
    json: Path
    picture: Path


def run_realism(dataset: str | Path, left: str | Path, right: str | Path | None = None, *,
                out: str | Path | None = None, frame: int = 0, mask: str | Path | None = None,
                real_disparity: str | Path | None = None, real_calib: str | Path | None = None,
                methods: tuple[str, ...] = METHODS, surface_only: bool = False) -> RealismOutput:
    """Compare frame ``frame`` of ``dataset`` with the real ``left`` (and ``right``) image and write the table
    (Markdown, JSON) and the picture into ``out`` (default ``DATASET/realism``). Every input is checked
    before anything is written (:class:`~rgbd2scene.errors.UserError` on a bad one)."""
    from rgbd2scene.files.atomic import ensure_output_dir, write_json, write_text
    from rgbd2scene.files.images import write_image
    from rgbd2scene.realism.picture import realism_picture

    unknown = [name for name in methods if name not in METHODS]
    if unknown:
        from rgbd2scene.errors import UserError

        raise UserError(f"realism: unknown method {', '.join(unknown)} (choose from {', '.join(METHODS)}, or none)")
    inputs = load_inputs(dataset, left, right, frame=frame, mask=mask, real_disparity=real_disparity,
                         real_calib=real_calib, surface_only=surface_only)
    report = compare(inputs, methods)
    within = len(report.rows) - len(report.misses)
    masks = {eye: inputs.eye_mask(eye) for eye in inputs.real}
    title = (f"{Path(dataset).name} frame {frame} vs real: {within} of {len(report.rows)} figures render/real "
             "within their goal band")
    picture = realism_picture(inputs.real, inputs.render, masks, title)
    folder = ensure_output_dir(out if out is not None else Path(dataset) / "realism")
    paths = RealismOutput(report, folder / "realism.md", folder / "realism.json", folder / "realism.png")
    write_text(paths.markdown, markdown_report(report))
    write_json(paths.json, report.to_dict())
    write_image(paths.picture, picture)
    return paths
