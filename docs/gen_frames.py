"""Draw docs/figures/frames.png: the world and camera frames and the pixel grid of CONVENTIONS section 1.

Run by `make docs-figures` (numpy and OpenCV only); the picture is committed.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

INK, RED, GREEN, BLUE, GREY = (40, 40, 40), (40, 40, 200), (40, 150, 40), (200, 90, 30), (170, 170, 170)


def arrow(img, a, b, colour, label):
    cv2.arrowedLine(img, a, b, colour, 2, cv2.LINE_AA, tipLength=0.12)
    cv2.putText(img, label, (b[0] + 6, b[1] + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)


def text(img, s, at, colour=INK, scale=0.45):
    cv2.putText(img, s, at, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def top_view(img):
    """Left panel: the rig seen from above (x right, z forward; y points into the page)."""
    text(img, "seen from above (y points into the page)", (20, 25), INK, 0.5)
    xs = np.linspace(30, 400, 200)
    zs = 110 + 18 * np.sin(xs / 40.0)  # the tissue surface, ahead of the cameras
    cv2.polylines(img, [np.stack([xs, zs], 1).astype(np.int32)], False, (90, 120, 200), 3, cv2.LINE_AA)
    text(img, "tissue (mesh = back-projected capture)", (120, 70), (90, 120, 200))
    capture, left, right = (60, 335), (190, 300), (250, 300)
    for (x, y), name, colour, at in ((capture, "world = capture camera (frame 0)", GREY, (-40, 30)),
                                     (left, "left eye", RED, (-60, 25)), (right, "right eye", BLUE, (-20, 25))):
        cv2.circle(img, (x, y), 5, colour, -1, cv2.LINE_AA)
        arrow(img, (x, y), (x + 45, y), colour, "x")
        arrow(img, (x, y), (x, y - 45), colour, "z")
        text(img, name, (x + at[0], y + at[1]), colour)
    for eye in (left, right):  # each eye's ray to one surface point
        cv2.line(img, eye, (220, 110 + int(18 * np.sin(220 / 40.0))), (120, 120, 120), 1, cv2.LINE_AA)
    cv2.line(img, (190, 285), (250, 285), INK, 1, cv2.LINE_AA)
    text(img, "B", (215, 280))
    text(img, "right = left + B along left x (rectified)", (20, 385))
    text(img, "T_world_cam: camera -> world, OpenCV axes", (20, 405))


def image_view(img, x0):
    """Right panel: the image plane, pixel (u, v) = (column, row) with its centre at (u, v)."""
    text(img, "image of one eye (x right, y down)", (x0 + 10, 25), INK, 0.5)
    cell, n, ox, oy = 48, 5, x0 + 50, 70
    for i in range(n + 1):
        cv2.line(img, (ox + i * cell, oy), (ox + i * cell, oy + n * cell), GREY, 1)
        cv2.line(img, (ox, oy + i * cell), (ox + n * cell, oy + i * cell), GREY, 1)
    for v in range(n):
        for u in range(n):
            cv2.circle(img, (ox + u * cell + cell // 2, oy + v * cell + cell // 2), 2, INK, -1, cv2.LINE_AA)
    c = (ox + cell // 2, oy + cell // 2)
    arrow(img, c, (c[0] + 2 * cell, c[1]), RED, "u")
    arrow(img, c, (c[0], c[1] + 2 * cell), GREEN, "v")
    text(img, "(0, 0) is the centre of the first pixel", (x0 + 10, oy + n * cell + 30))
    text(img, "cx = (W-1)/2 for a centred principal point", (x0 + 10, oy + n * cell + 50))
    text(img, "X = (u-cx) z/fx, Y = (v-cy) z/fy, Z = z (planar)", (x0 + 10, oy + n * cell + 70))
    text(img, "left (u, v) <-> right (u - d, v), d = fx B / z", (x0 + 10, oy + n * cell + 90))


def draw() -> np.ndarray:
    img = np.full((420, 820, 3), 255, np.uint8)
    top_view(img)
    cv2.line(img, (430, 10), (430, 410), GREY, 1)
    image_view(img, 440)
    return img


if __name__ == "__main__":
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent / "figures" / "frames.png"
    cv2.imwrite(str(out), draw())
