"""What an older SD scope's video chain does to the 8-bit image: chroma subsampling, JPEG compression and
interlacing (one field per frame, its rows doubled, as deinterlaced SD recordings such as Hamlyn's look).
All deterministic (OpenCV's codecs).
"""

from __future__ import annotations

import numpy as np


def chroma_420(rgb: np.ndarray) -> np.ndarray:
    """4:2:0 chroma subsampling: Cb and Cr averaged over 2x2 blocks and repeated (uint8 RGB in and out)."""
    import cv2

    ycc = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YCrCb).astype(np.float32)
    h, w = ycc.shape[:2]
    hp, wp = h + h % 2, w + w % 2
    pad = np.pad(ycc, ((0, hp - h), (0, wp - w), (0, 0)), mode="edge")
    for c in (1, 2):
        blocks = pad[..., c].reshape(hp // 2, 2, wp // 2, 2).mean(axis=(1, 3))
        pad[..., c] = np.repeat(np.repeat(blocks, 2, axis=0), 2, axis=1)
    ycc = np.clip(np.rint(pad[:h, :w]), 0, 255).astype(np.uint8)
    return cv2.cvtColor(ycc, cv2.COLOR_YCrCb2RGB)


def jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    """Encode as JPEG at ``quality`` (1-100) and decode: its block and ringing artefacts (uint8 RGB)."""
    import cv2

    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise OSError("OpenCV could not encode the JPEG")
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])


def single_field(rgb: np.ndarray, field: int) -> np.ndarray:
    """Keep the rows of one field (``field`` 0: even rows, 1: odd rows) and repeat each into its neighbour."""
    out = np.array(rgb, copy=True)
    h = out.shape[0]
    src = np.arange(h) - (np.arange(h) % 2) + field
    return out[np.minimum(src, h - 1 - ((h - 1 - field) % 2))]
