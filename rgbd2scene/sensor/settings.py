"""Every setting of the sensor model (one dataclass: CLI flags, batch keys and dataset.json's ``"sensor"``).

Defaults measured on the real Hamlyn phantom frame ``f7_dynamic_deint_L_0100.png`` (LEFT eye, 360x288;
``../shared/rgbd_samples/hamlyn_silicone_heart_phantom_stereo``) with :mod:`rgbd2scene.sensor.estimate`; the
RIGHT eye is held out (``benchmarks/bench_sensor.py`` prints both):

- ``target`` 69: trimmed mean (2nd-98th percentile) of its 8-bit luma, 68.8 (right eye 63.1; plain means 70.0
  and 65.7).
- ``noise_shot`` 2.5e-4, ``noise_read`` 0: the Poisson-Gaussian fit var = a x + b of its linear-domain noise
  (:func:`~rgbd2scene.sensor.estimate.fit_poisson_gaussian`, sRGB decoding; right eye a = 2.2e-4, b = 0).
  The fitted b is 0: below linear 0.02 one 8-bit code step exceeds the read noise, so this frame cannot see it.
- ``vignetting_k1`` 0, ``vignetting_k2`` 0 (a flat map: no optical vignetting on top of the render): the
  vignetting must add only what the render lacks, and the render already falls off more than the real frame.
  The real frame's radial fall-off (``radial_falloff`` over the whole frame: k1 -1.72, k2 0.50, V(0.5) 0.60,
  the defaults until session 8) is the scope's light and its optics together, and the render has the light
  (the lamps at the tip: inverse square, angle of incidence). Measured by ``benchmarks/bench_vignetting.py``
  (``benchmarks/results/vignetting.md``): the digital twin of the frame (``--path capture``, the same view)
  rendered with ``--no-vignetting --no-noise`` at a fixed exposure that clips 0.07 % of its pixels; on the
  pixels where the twin sees its surface inside the frame's valid area, the 90th percentile of linear
  luminance in 10 rings (:func:`~rgbd2scene.sensor.estimate.radial_profile`) of the real frame over the
  render's, fitted as s (1 + k1 rho^2 + k2 rho^4) with a free level s
  (:func:`~rgbd2scene.sensor.estimate.vignetting_from_profiles`), gives k1 +0.29, k2 +1.19 (right eye -0.29,
  +3.22, V >= 0.993 everywhere): V >= 1 at every rho, so the vignetting map, clipped at 1, is flat. Per ring
  the ratio over s grows from about 1 at rho 0.1-0.2 to 1.6 at rho 0.7-0.8 (right 2.3 at rho 0.74): without
  vignetting the twin is already darker towards the rim than the real frame. The reason: the twin's texture is
  the real frame itself, whose fall-off is baked in (the unlit twin's profile matches the real one within 0.07
  per ring), and the render's light adds its own. Against the light's shading alone (render / unlit render)
  the real frame would leave a rim fall-off (V(0.7) 0.61, right eye 0.27) under a mid-field bump above 1 that
  no optics makes: not stable enough between the eyes to be a default, and it only applies to a texture
  without baked light. The real frame's black corners (its field stop, rho > 0.9) lie outside the twin's
  surface and are not modelled by default; ``--vignetting-k1/-k2`` add a scope's optics.
- ``tone`` srgb, white balance neutral: one frame without a colour chart fixes neither; the scene's texture
  already holds the capture's own colours.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from rgbd2scene.options import OptionError, option
from rgbd2scene.sensor.tone import TONE_CURVES

EXPOSURE_MODES = ("auto", "fixed")
CHROMA_MODES = ("444", "420")


def parse_triple(text: str) -> tuple[float, float, float]:
    """``"1,0.9,1.1"`` -> (1.0, 0.9, 1.1)."""
    try:
        values = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        raise ValueError(f"expected three numbers like 1,0.9,1.1, got {text!r}") from None
    if len(values) != 3:
        raise ValueError(f"expected three numbers like 1,0.9,1.1, got {text!r}")
    return values


@dataclass
class SensorOptions:
    """The endoscope camera's exposure, sensor and optics effects on the RGB images (never the ground truth)."""

    exposure: str = option("auto", "auto (light power and gain follow the image) or fixed",
                           choices=EXPOSURE_MODES, flag="--exposure")
    exposure_gain: float = option(1.0, "fixed exposure: the sensor gain (light at full power)")
    target: float = option(69.0, "auto exposure: the trimmed-mean 8-bit luma it aims at (Hamlyn phantom, left eye)",
                           flag="--exposure-target")
    ae_speed: float = option(0.3, "auto exposure: weight of the newest frame in its smoothing (0-1]")
    ae_window: int = option(10, "auto exposure: frames it remembers (the recursion restarts nowhere else)")
    # 1 % (2 % until session 8): without the old vignetting the bundled sample needs 0.021 of the light at 2 cm
    # (benchmarks/results/sensor.md); 1 % keeps the near limit of a correct exposure at about 1.4 cm, as before
    light_min: float = option(0.01, "auto exposure: lowest light power, as a share of the scene's light")
    gain_max: float = option(16.0, "auto exposure: highest sensor gain")
    vignetting: bool = option(True, "no vignetting")
    vignetting_k1: float = option(0.0, "vignetting V = 1 + k1 rho^2 + k2 rho^4 (rho: radius / half-diagonal; "
                                  "the optics only: the light's fall-off is rendered)")
    vignetting_k2: float = option(0.0, "vignetting rho^4 coefficient")
    noise: bool = option(True, "no sensor noise")
    noise_shot: float = option(2.5e-4, "Poisson-Gaussian noise: variance per unit signal (at gain 1, linear 0-1)")
    noise_read: float = option(0.0, "Poisson-Gaussian noise: signal-independent variance (at gain 1)")
    white_balance: tuple[float, float, float] = option((1.0, 1.0, 1.0), "white-balance gains R,G,B (default 1,1,1)",
                                                       parse=parse_triple, metavar="R,G,B")
    tone: str = option("srgb", "tone curve", choices=TONE_CURVES)
    gamma: float = option(2.2, "tone curve gamma (with --tone gamma)")
    chroma: str = option("444", "chroma subsampling: 444 (none) or 420", choices=CHROMA_MODES)
    jpeg_quality: int = option(0, "JPEG compression artefacts at this quality (1-100; 0: none)")
    interlace: bool = option(False, "one field per frame, rows doubled (older SD scopes)")
    clean: bool = option(False, "also write the image without noise and compression to {eye}/rgb_clean/")
    motion_blur: float = option(0.0, "motion blur: shutter time in frames, centred on the frame (0: off)")
    focus_distance: float = option(0.0, "depth of field: focus distance in metres (0: off)")
    aperture_mm: float = option(0.5, "depth of field: the lens's aperture (entrance pupil) diameter, mm; a "
                                "pixel's blur circle is fx * D * |1/z - 1/z_focus| pixels")

    def validated(self) -> SensorOptions:
        """A checked copy; :class:`OptionError` names the bad field."""
        checks = [("exposure", self.exposure in EXPOSURE_MODES, f"choose auto or fixed, got {self.exposure!r}"),
                  ("exposure_gain", self.exposure_gain > 0, "must be positive"),
                  ("target", 0 < self.target < 255, "must be between 0 and 255"),
                  ("ae_speed", 0 < self.ae_speed <= 1, "must be in (0, 1]"),
                  ("ae_window", int(self.ae_window) >= 1, "must be at least 1"),
                  ("light_min", 0 < self.light_min <= 1, "must be in (0, 1]"),
                  ("gain_max", self.gain_max >= 1, "must be at least 1"),
                  ("noise_shot", self.noise_shot >= 0, "must not be negative"),
                  ("noise_read", self.noise_read >= 0, "must not be negative"),
                  ("white_balance", len(self.white_balance) == 3 and min(self.white_balance) > 0,
                   "must be three positive gains"),
                  ("tone", self.tone in TONE_CURVES, f"choose one of {', '.join(TONE_CURVES)}"),
                  ("gamma", self.gamma > 0, "must be positive"),
                  ("chroma", str(self.chroma) in CHROMA_MODES, f"choose one of {', '.join(CHROMA_MODES)}"),
                  ("jpeg_quality", 0 <= int(self.jpeg_quality) <= 100, "must be 0 (off) to 100"),
                  ("motion_blur", 0 <= self.motion_blur <= 2, "must be 0 (off) to 2 frames"),
                  ("focus_distance", self.focus_distance >= 0, "must not be negative"),
                  ("aperture_mm", self.aperture_mm > 0, "must be positive")]
        for name, ok, message in checks:
            if not ok:
                raise OptionError(name, f"{message}, got {getattr(self, name)!r}")
        return replace(self, white_balance=tuple(float(v) for v in self.white_balance), chroma=str(self.chroma),
                       ae_window=int(self.ae_window), jpeg_quality=int(self.jpeg_quality))

    def to_dict(self) -> dict:
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict) -> SensorOptions:
        d = dict(d)
        if "white_balance" in d:
            d["white_balance"] = tuple(d["white_balance"])
        return cls(**d)

    @classmethod
    def ideal(cls) -> SensorOptions:
        """No effect on: fixed exposure at gain 1, no noise, vignetting, compression or blur (sRGB encoding)."""
        return cls(exposure="fixed", vignetting=False, noise=False)
