"""The side-by-side picture of ``rgbd2scene realism``: per eye, the real frame, the rendered one, their
luminance difference and both contrast spectra (OpenCV drawing only)."""

from __future__ import annotations

import cv2
import numpy as np

from rgbd2scene.pictures.overview import BACKGROUND, TEXT, fit_cell, label_panel, put_text
from rgbd2scene.realism import measures as m

#: Luminance difference (render - real) shown at full colour.
DIFF_SCALE = 64.0
#: Spectrum bands of the spectra panel: log-spaced edges, cycles per pixel.
SPECTRUM_EDGES = np.geomspace(0.01, 0.5, 17)
REAL_COLOUR = (90, 220, 120)
RENDER_COLOUR = (255, 160, 40)
MASKED = (60, 60, 60)
TITLE_H = 34


def difference_image(real: np.ndarray, render: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """RGB uint8: render - real luminance, red where the render is brighter, blue where darker, black where
    equal (full colour at ``DIFF_SCALE`` levels); pixels outside the mask grey."""
    t = np.clip((m.luminance(render) - m.luminance(real)) / DIFF_SCALE, -1.0, 1.0)
    out = np.zeros((*t.shape, 3), np.uint8)
    out[..., 0] = np.round(255 * np.maximum(t, 0))
    out[..., 2] = np.round(255 * np.maximum(-t, 0))
    if mask is not None:
        out[~mask] = MASKED
    return out


def spectrum_panel(real: np.ndarray, render: np.ndarray, mask: np.ndarray | None, width: int,
                   height: int) -> np.ndarray:
    """A plot of the band-averaged power (dB) of both contrast images against log frequency."""
    curves = {}
    for name, image in (("real", real), ("render", render)):
        spectrum = m.power_spectrum(m.contrast_image(image, mask), mask)
        curves[name] = m.band_power_db([spectrum], SPECTRUM_EDGES)
    panel = np.full((height, width, 3), BACKGROUND, np.uint8)
    finite = np.concatenate([c[np.isfinite(c)] for c in curves.values()])
    if not finite.size:
        return panel
    lo, hi = float(finite.min()) - 3, float(finite.max()) + 3
    x0, x1, y0, y1 = 44, width - 10, 40, height - 30
    cv2.rectangle(panel, (x0, y0), (x1, y1), (90, 90, 90), 1)
    log_f = np.log10(np.sqrt(SPECTRUM_EDGES[:-1] * SPECTRUM_EDGES[1:]))
    xs = x0 + (log_f - log_f[0]) / (log_f[-1] - log_f[0]) * (x1 - x0)
    for name, colour in (("real", REAL_COLOUR), ("render", RENDER_COLOUR)):
        c = curves[name]
        ok = np.isfinite(c)
        ys = y1 - (c - lo) / (hi - lo) * (y1 - y0)
        pts = np.stack([xs[ok], ys[ok]], axis=1).round().astype(np.int32)
        cv2.polylines(panel, [pts], False, colour, 2, cv2.LINE_AA)
    put_text(panel, f"{hi:.0f} dB", (2, y0 + 12), 0.4)
    put_text(panel, f"{lo:.0f}", (2, y1), 0.4)
    put_text(panel, f"{SPECTRUM_EDGES[0]:g}", (x0 - 10, height - 10), 0.4)
    put_text(panel, f"{SPECTRUM_EDGES[-1]:g} c/px", (x1 - 70, height - 10), 0.4)
    put_text(panel, "real", (x1 - 110, y0 + 18), 0.45, REAL_COLOUR)
    put_text(panel, "render", (x1 - 60, y0 + 18), 0.45, RENDER_COLOUR)
    return panel


def realism_picture(real: dict[str, np.ndarray], render: dict[str, np.ndarray],
                    masks: dict[str, np.ndarray | None], title: str) -> np.ndarray:
    """RGB uint8: a title band, then one row per eye of four panels (real, render, difference, spectra); the
    pixels outside an eye's mask (None: all inside) are dimmed."""
    h, w = next(iter(real.values())).shape[:2]
    cell_w = int(np.clip(w, 256, 480))
    cell_h = max(int(round(cell_w * h / w)), 160)
    rows = []
    for eye in real:
        mask = masks.get(eye)
        shown = [real[eye], render[eye]]
        if mask is not None:
            shown = [np.where(mask[..., None], img, (img * 0.3).astype(np.uint8)) for img in shown]
        cells = [label_panel(fit_cell(shown[0], cell_w, cell_h), f"real {eye}"),
                 label_panel(fit_cell(shown[1], cell_w, cell_h), f"render {eye}"),
                 label_panel(fit_cell(difference_image(real[eye], render[eye], mask), cell_w, cell_h,
                                      cv2.INTER_NEAREST), f"render-real +-{DIFF_SCALE:g}"),
                 label_panel(spectrum_panel(real[eye], render[eye], mask, cell_w, cell_h), "contrast spectra")]
        rows.append(np.hstack(cells))
    body = np.vstack(rows)
    band = np.full((TITLE_H, body.shape[1], 3), BACKGROUND, np.uint8)
    put_text(band, title, (8, 23), 0.55, TEXT)
    return np.vstack([band, body])
