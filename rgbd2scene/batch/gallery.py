"""``ROOT/index.html``: a static gallery of every sequence of a batch build (no server, no script).

Per sequence: thumbnails of the middle frame (both eyes and the left eye's maps, ``ROOT/gallery/<sequence>/``),
its split, status, capture, path, seed, the settings its variations drew, the first line of its error, and
links to its contact sheet, dataset folder, scene folder and the capture's overview. Every link is relative,
so ROOT can be moved or served as it is.
"""

from __future__ import annotations

import html
from pathlib import Path

from rgbd2scene.batch.manifest import Row, counts
from rgbd2scene.batch.plan import Plan
from rgbd2scene.files.atomic import write_text
from rgbd2scene.files.images import write_image
from rgbd2scene.pictures.overview import fit_cell
from rgbd2scene.scene.folder import OVERVIEW

INDEX = "index.html"
GALLERY = "gallery"
THUMB_W = 192
#: Thumbnails shown per sequence, in this order (the keys of rgbd2scene.pictures.contact_sheet.frame_panels).
THUMBS = ("left_rgb", "right_rgb", "depth", "disparity", "normals", "flow_forward", "segmentation")
STYLE = """
body { font-family: sans-serif; margin: 1.5em; background: #fafafa; color: #222; }
table.counts td, table.counts th { padding: 0.2em 0.8em; text-align: right; }
section.split { margin-top: 1.5em; }
div.sequence { background: white; border: 1px solid #ddd; border-radius: 6px; padding: 0.6em 0.8em; margin: 0.6em 0; }
div.sequence h3 { margin: 0 0 0.3em 0; font-size: 1.05em; }
span.status { border-radius: 4px; padding: 0.05em 0.5em; color: white; font-size: 0.85em; }
span.done { background: #2e7d32; } span.failed { background: #c62828; } span.pending { background: #757575; }
p.settings { margin: 0.2em 0; font-size: 0.9em; color: #444; }
p.error { margin: 0.2em 0; font-family: monospace; color: #c62828; white-space: pre-wrap; }
figure { display: inline-block; margin: 0.2em; text-align: center; }
figure img { display: block; border: 1px solid #ccc; }
figcaption { font-size: 0.75em; color: #555; }
"""


def write_thumbnails(root: Path, sequence: str, frames: int) -> list[tuple[str, str]]:
    """Thumbnails of the sequence's middle frame under ``ROOT/gallery/<sequence>/`` (made once: a done sequence
    does not change); returns (relative path, label) pairs."""
    from rgbd2scene.pictures.contact_sheet import frame_panels

    folder = root / GALLERY / sequence
    wanted = {key: folder / f"{key}.png" for key in THUMBS}
    labels = {}
    if not all(p.is_file() for p in wanted.values()):
        for panel in frame_panels(root / sequence, (frames - 1) // 2):
            if panel.key in wanted:
                h, w = panel.image.shape[:2]
                write_image(wanted[panel.key], fit_cell(panel.image, THUMB_W, max(1, round(THUMB_W * h / w))))
                labels[panel.key] = panel.label
    return [(p.relative_to(root).as_posix(), labels.get(key, key.replace("_", " ")))
            for key, p in wanted.items() if p.is_file()]


def _link(root: Path, path: Path, text: str) -> str:
    if not path.exists():
        return ""
    return f'<a href="{html.escape(path.relative_to(root).as_posix())}">{html.escape(text)}</a>'


def _sequence_html(root: Path, row: Row, scenes: str) -> str:
    e = html.escape
    settings = [f"capture {row.capture}", f"path {row.path}", f"seed {row.seed}",
                f"{row.frames_done}/{row.frames} frames"] + [f"{k} {v}" for k, v in sorted(row.settings.items())]
    links = [_link(root, root / row.sequence / "contact_sheet.png", "contact sheet"),
             _link(root, root / row.sequence / "dataset.json", "dataset.json"),
             _link(root, root / scenes / row.sequence / "scene.json", "scene"),
             _link(root, root / scenes / row.sequence / OVERVIEW, "capture overview")]
    parts = [f'<div class="sequence" id="{e(row.sequence)}">',
             f'<h3>{e(row.sequence)} <span class="status {e(row.status)}">{e(row.status)}</span></h3>',
             f'<p class="settings">{e(" · ".join(settings))}</p>',
             f'<p class="settings">{" · ".join(link for link in links if link)}</p>']
    if row.error:
        parts.append(f'<p class="error">{e(row.error)}</p>')
    if row.status == "done":
        for src, label in write_thumbnails(root, row.sequence, row.frames):
            parts.append(f'<figure><img src="{e(src)}" alt="{e(row.sequence)} {e(label)}" width="{THUMB_W}">'
                         f'<figcaption>{e(label)}</figcaption></figure>')
    parts.append("</div>")
    return "\n".join(parts)


def write_gallery(root: str | Path, plan: Plan, rows: list[Row], scenes: str = "scenes") -> Path:
    """Write ``ROOT/index.html`` (and the thumbnails it shows); returns its path."""
    root = Path(root)
    splits, table = counts(rows)
    head = "<tr><th></th>" + "".join(f"<th>{html.escape(sp)}</th>" for sp in [*splits, "total"]) + "</tr>"
    cells = "".join(f"<tr><th>{status}</th>" + "".join(f"<td>{n}</td>" for n in by_split.values()) + "</tr>"
                    for status, by_split in table.items())
    body = []
    for split in splits:
        body.append(f'<section class="split"><h2>{html.escape(split)}</h2>')
        body += [_sequence_html(root, r, scenes) for r in rows if r.split == split]
        body.append("</section>")
    title = f"rgbd2scene batch: {root.resolve().name}"
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title><style>{STYLE}</style></head>
<body>
<h1>{html.escape(title)}</h1>
<p>{len(rows)} sequences from {len({r.capture for r in rows})} captures, {sum(r.frames for r in rows)} frames
(configuration seed {plan.config.seed}; <a href="manifest.csv">manifest.csv</a>, <a href="config.json">config.json</a>).
Thumbnails show each sequence's middle frame: both eyes, then the left eye's ground truth.</p>
<table class="counts">{head}{cells}</table>
{chr(10).join(body)}
</body></html>
"""
    path = root / INDEX
    write_text(path, page)
    return path
