"""The sensor pipeline: one eye's linear scene-referred RGB -> the 8-bit sRGB image a scope would deliver.

:func:`develop` is a pure function of (linear image, frame, eye, settings, exposure, seed); the exposure is
the state the auto exposure carries between frames (:mod:`rgbd2scene.sensor.exposure`). Any step that acts on
the linear image (an environment effect such as smoke, a lens-distortion resampling) runs before it. In order:

1. exposure, optical part: times ``exposure.light`` (the light source's share of the scene's light);
2. vignetting: times V(rho) (:mod:`~rgbd2scene.sensor.vignetting`; the optics only, flat by default: the
   light's fall-off is in the render already);
3. sensor gain: times ``exposure.gain``; this is the raw signal, 0-1 full scale;
4. Poisson-Gaussian noise on the raw signal (:mod:`~rgbd2scene.sensor.noise`), then clipping at full scale
   (highlights saturate);
5. white balance gains, the tone curve (:mod:`~rgbd2scene.sensor.tone`), rounding to 8 bits;
6. video chain (:mod:`~rgbd2scene.sensor.video`): one field per frame, 4:2:0 chroma, JPEG.

The clean image (``rgb_clean``) is the same without steps 4 and 6.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.sensor.exposure import Exposure
from rgbd2scene.sensor.noise import poisson_gaussian, rng_for
from rgbd2scene.sensor.settings import SensorOptions
from rgbd2scene.sensor.tone import encode, to_uint8, white_balance
from rgbd2scene.sensor.video import chroma_420, jpeg, single_field
from rgbd2scene.sensor.vignetting import sensor_vignetting


@dataclass
class Developed:
    """One eye's developed image (uint8 RGB) and, with ``clean`` asked for, its noise-free twin."""

    rgb: np.ndarray
    clean: np.ndarray | None = None


def develop_clean(linear: np.ndarray, total_exposure: float, options: SensorOptions,
                  vignetting: np.ndarray | None = None) -> np.ndarray:
    """Encoded (0-1, float) clean image at exposure ``total_exposure`` (no noise, no quantisation)."""
    raw = np.asarray(linear, dtype=np.float32) * np.float32(total_exposure)
    if vignetting is not None:
        raw = raw * vignetting[..., None]
    return encode(white_balance(np.clip(raw, 0.0, 1.0), options.white_balance), options.tone, options.gamma)


def develop(linear: np.ndarray, frame: int, eye: str, options: SensorOptions, exposure: Exposure,
            seed: int = 0) -> Developed:
    """The 8-bit image of one eye of one frame.

    Parameters
    ----------
    linear
        float32 (H, W, 3), linear scene-referred RGB as Cycles renders it (the scene's light at full power).
    frame, eye
        Frame index and ``"left"``/``"right"``: with ``seed`` they seed the noise.
    options
        :class:`~rgbd2scene.sensor.settings.SensorOptions` (validated).
    exposure
        Light share and sensor gain of this frame (:func:`~rgbd2scene.sensor.exposure.frame_exposure`).
    """
    linear = np.asarray(linear, dtype=np.float32)
    if linear.ndim != 3 or linear.shape[2] != 3:
        raise ValueError(f"linear image must be (H, W, 3), got {linear.shape}")
    h, w = linear.shape[:2]
    vign = sensor_vignetting(options, w, h)
    optical = linear * np.float32(exposure.light)
    if vign is not None:
        optical = optical * vign[..., None]
    raw = optical * np.float32(exposure.gain)
    clean = None
    if options.clean or not options.noise:
        clean = to_uint8(encode(white_balance(np.clip(raw, 0.0, 1.0), options.white_balance), options.tone,
                                options.gamma))
    if options.noise:
        raw = poisson_gaussian(raw, options.noise_shot, options.noise_read, exposure.gain, rng_for(seed, frame, eye))
        rgb = to_uint8(encode(white_balance(np.clip(raw, 0.0, 1.0), options.white_balance), options.tone,
                              options.gamma))
    else:
        rgb = clean
    rgb = video_chain(rgb, frame, options)
    return Developed(rgb, clean if options.clean else None)


def video_chain(rgb: np.ndarray, frame: int, options: SensorOptions) -> np.ndarray:
    """Interlacing (field ``frame % 2``), chroma subsampling and JPEG, each when switched on."""
    if options.interlace:
        rgb = single_field(rgb, frame % 2)
    if options.chroma == "420":
        rgb = chroma_420(rgb)
    if options.jpeg_quality:
        rgb = jpeg(rgb, options.jpeg_quality)
    return rgb
