"""The sensor model's pure functions: noise law, auto exposure, vignetting, tone, video chain, estimators."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd2scene.options import OptionError
from rgbd2scene.sensor import Exposure, SensorOptions, develop, frame_exposure, meter, smoothed_log_exposure
from rgbd2scene.sensor.estimate import (
    brightness_stats,
    fit_poisson_gaussian,
    linear_luminance,
    noise_curve,
    optical_vignetting,
    radial_falloff,
    radial_profile,
    radius_map,
    trimmed_mean,
    vignetting_from_profiles,
)
from rgbd2scene.sensor.noise import poisson_gaussian, rng_for
from rgbd2scene.sensor.tone import decode, encode, luminance
from rgbd2scene.sensor.video import chroma_420, jpeg, single_field
from rgbd2scene.sensor.vignetting import sensor_vignetting, vignetting_map

HAMLYN = "hamlyn_silicone_heart_phantom_stereo"
#: radial_falloff of the whole real left frame (the sensor defaults of sessions 1-7).
REAL_FALLOFF_K1 = -1.72


def _flat(level: float, h: int = 64, w: int = 96) -> np.ndarray:
    return np.full((h, w, 3), level, np.float32)


@pytest.mark.parametrize("shot,read,gain", [(2.5e-4, 0.0, 1.0), (1e-3, 4e-6, 4.0), (0.0, 1e-4, 2.0)])
def test_noise_variance_follows_the_poisson_gaussian_law(shot, read, gain):
    rng = rng_for(3, 7, "left")
    for level in (0.05, 0.2, 0.6):
        y = poisson_gaussian(np.full(200_000, level), shot, read, gain, rng)
        expected = shot * gain * level + read * gain**2
        assert abs(y.mean() - level) < 5 * np.sqrt(expected / y.size) + 1e-7
        assert y.var() == pytest.approx(expected, rel=0.03)


def test_noise_is_reproducible_per_seed_frame_and_eye():
    lin = _flat(0.1)
    opts = SensorOptions(exposure="fixed", vignetting=False).validated()
    a = develop(lin, 4, "left", opts, Exposure(1.0, 2.0), seed=1).rgb
    assert np.array_equal(a, develop(lin, 4, "left", opts, Exposure(1.0, 2.0), seed=1).rgb)
    for other in [dict(frame=5, eye="left", seed=1), dict(frame=4, eye="right", seed=1),
                  dict(frame=4, eye="left", seed=2)]:
        b = develop(lin, other["frame"], other["eye"], opts, Exposure(1.0, 2.0), seed=other["seed"]).rgb
        assert not np.array_equal(a, b)


def test_ideal_sensor_is_plain_srgb_encoding():
    lin = np.random.default_rng(0).random((16, 24, 3)).astype(np.float32)
    out = develop(lin, 0, "left", SensorOptions.ideal().validated(), Exposure(1.0, 1.0)).rgb
    expected = np.rint(encode(lin) * 255)
    assert np.abs(out.astype(int) - expected).max() <= 1  # rounding of float32 vs float64 only
    assert np.array_equal(decode(encode(np.linspace(0, 1, 11))), np.linspace(0, 1, 11).clip(0, 1)) or np.allclose(
        decode(encode(np.linspace(0, 1, 11))), np.linspace(0, 1, 11), atol=1e-12)


def test_auto_exposure_converges_to_the_target():
    opts = SensorOptions(noise=False).validated()
    # dim scene, smooth at the meter's stride (METER_STRIDE 4 sees every 8x8 block alike): the metering's
    # subsample then has the image's own luma distribution, as it has on a render
    lin = (np.kron(np.random.default_rng(1).random((8, 12, 3)), np.ones((8, 8, 1))) * 0.1).astype(np.float32)
    log_e = meter(lin, opts)
    exp = frame_exposure([log_e], opts)
    assert exp.light == 1.0 and 1.0 < exp.gain < opts.gain_max
    out = develop(lin, 0, "left", opts, exp).rgb
    assert trimmed_mean(luminance(out.astype(float))) == pytest.approx(opts.target, abs=1.0)
    # a bright scene dims the light first, the gain stays at 1
    bright = frame_exposure([meter(lin * 200, opts)], opts)
    assert bright.gain == 1.0 and bright.light < 1.0


def test_auto_exposure_steps_smoothly_and_does_not_flicker():
    opts = SensorOptions().validated()
    # a step in scene brightness: the exposure moves monotonically towards the new value
    metered = [0.0] * 12 + [1.0] * 20
    series = [smoothed_log_exposure(metered[:i + 1], opts) for i in range(len(metered))]
    steps = np.diff(series)
    assert np.all(steps >= -1e-12) and series[11] == 0.0
    newest = 1.0 / ((1.0 - opts.ae_speed) ** np.arange(opts.ae_window)).sum()
    assert steps.max() <= newest + 1e-9  # never jumps by more than the newest frame's weight
    assert series[-1] == pytest.approx(1.0, abs=1e-9)  # the window forgets the old value completely
    # metering jitter of 0.2 (log units) frame to frame: the exposure jitters far less
    jitter = np.random.default_rng(2).normal(0.0, 0.2, 200)
    smooth = [smoothed_log_exposure(jitter[:i + 1], opts) for i in range(len(jitter))]
    assert np.std(np.diff(smooth[20:])) < 0.3 * np.std(np.diff(jitter[20:]))


def test_auto_exposure_recursion_depends_only_on_the_window():
    opts = SensorOptions(ae_window=4).validated()
    a = smoothed_log_exposure([9.0, 9.0, 1.0, 2.0, 3.0, 4.0], opts)
    b = smoothed_log_exposure([-5.0, 1.0, 2.0, 3.0, 4.0], opts)
    assert a == b


def test_fixed_exposure():
    opts = SensorOptions(exposure="fixed", exposure_gain=3.0).validated()
    assert frame_exposure([], opts) == Exposure(1.0, 3.0)


def test_vignetting_is_one_at_the_centre_and_symmetric():
    v = vignetting_map(65, 33, -0.8, 0.1)
    assert v[16, 32] == 1.0
    assert np.array_equal(v, v[::-1]) and np.array_equal(v, v[:, ::-1])
    assert v[0, 0] < v[16, 0] < 1.0 and v.min() >= 0.0
    assert np.all(np.diff(v[16, 32:]) <= 0)  # falls off outwards


def test_video_chain():
    rng = np.random.default_rng(4)
    img = rng.integers(0, 256, (33, 48, 3), dtype=np.uint8)
    f0, f1 = single_field(img, 0), single_field(img, 1)
    assert np.array_equal(f0[0::2], img[0::2]) and np.array_equal(f0[1::2], img[0:-1:2])
    assert np.array_equal(f1[1::2], img[1::2]) and np.array_equal(f1[-1], img[-2])
    sub = chroma_420(img)
    assert sub.shape == img.shape and not np.array_equal(sub, img)
    # luma survives subsampling (up to YCrCb rounding), colour detail does not
    y, ys = luminance(img.astype(float)), luminance(sub.astype(float))
    assert np.abs(y - ys).mean() < np.abs(img.astype(float) - sub).mean()
    assert np.array_equal(jpeg(img, 50), jpeg(img, 50)) and not np.array_equal(jpeg(img, 50), img)


def test_clean_image_is_the_noise_free_development():
    lin = np.random.default_rng(5).random((32, 48, 3)).astype(np.float32) * 0.5
    opts = SensorOptions(exposure="fixed", clean=True, jpeg_quality=70).validated()
    out = develop(lin, 2, "right", opts, Exposure(1.0, 1.0), seed=3)
    ideal = develop(lin, 2, "right", SensorOptions(exposure="fixed", noise=False).validated(), Exposure(1.0, 1.0))
    assert np.array_equal(out.clean, ideal.rgb) and not np.array_equal(out.rgb, out.clean)


def test_options_are_checked():
    with pytest.raises(OptionError, match="ae_speed|must be in"):
        SensorOptions(ae_speed=0).validated()
    with pytest.raises(OptionError):
        SensorOptions(white_balance=(1.0, -1.0, 1.0)).validated()
    rec = SensorOptions(white_balance=(1.0, 0.9, 1.1)).validated().to_dict()
    assert SensorOptions.from_dict(rec) == SensorOptions(white_balance=(1.0, 0.9, 1.1)).validated()


def test_estimators_recover_a_synthetic_camera():
    # a smooth gradient scene through a camera with known noise and vignetting
    h, w = 240, 320
    base = np.tile(np.linspace(0.03, 0.45, w, dtype=np.float32), (h, 1))
    lin = np.repeat(base[..., None], 3, axis=2)
    opts = SensorOptions(exposure="fixed", noise_shot=4e-4, noise_read=0.0, vignetting=False).validated()
    img = develop(lin, 0, "left", opts, Exposure(1.0, 1.0), seed=9).rgb
    a, b = fit_poisson_gaussian(noise_curve(img))
    assert a == pytest.approx(4e-4, rel=0.25) and b < 1e-5
    flat = develop(np.full((h, w, 3), 0.3, np.float32), 0, "left",
                   SensorOptions(exposure="fixed", noise=False, vignetting_k1=-0.8, vignetting_k2=0.1).validated(),
                   Exposure(1.0, 1.0)).rgb
    fall = radial_falloff(flat)
    assert fall.corner == pytest.approx(0.3, abs=0.08)
    stats = brightness_stats(flat)
    assert stats.clipped_fraction == 0.0 and stats.p95 > stats.p50


def _synthetic_view(h: int = 96, w: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """A textured scene's linear RGB (albedo in blobs, 0.2-0.6) under a light that falls off as
    1 / (1 + 3 rho^2): what a render holds before the sensor."""
    rng = np.random.default_rng(4)
    albedo = np.kron(rng.uniform(0.2, 0.6, (h // 8, w // 8)), np.ones((8, 8)))
    light = 1.0 / (1.0 + 3.0 * radius_map(w, h) ** 2)
    return np.repeat((albedo * light)[..., None], 3, axis=2).astype(np.float32), albedo


def test_optical_vignetting_recovers_the_fall_off_the_render_lacks():
    lin, _ = _synthetic_view()
    h, w = lin.shape[:2]
    ideal = SensorOptions(exposure="fixed", noise=False, vignetting=False).validated()
    render = develop(lin, 0, "left", ideal, Exposure(1.0, 0.8)).rgb
    # the "real" camera: the same scene through optics with V = 1 - 0.6 rho^2 + 0.1 rho^4, at another exposure
    optics = SensorOptions(exposure="fixed", noise=False, vignetting_k1=-0.6, vignetting_k2=0.1).validated()
    real = develop(lin, 0, "left", optics, Exposure(1.0, 1.3)).rgb
    fit = optical_vignetting(real, render, border=2)
    assert fit.k1 == pytest.approx(-0.6, abs=0.05) and fit.k2 == pytest.approx(0.1, abs=0.08)
    assert fit.at(0.8) == pytest.approx(1 - 0.6 * 0.64 + 0.1 * 0.64**2, abs=0.02)
    # the render's own fall-off (the light) is not counted: the real frame's whole fall-off is much steeper
    assert radial_falloff(real, border=2).at(0.8) < fit.at(0.8) - 0.2
    # no optics: nothing to add, whatever the exposure; a mask keeps its pixels only
    same = develop(lin, 0, "left", ideal, Exposure(1.0, 1.3)).rgb
    mask = np.zeros((h, w), bool)
    mask[:, : w // 2 + 20] = True
    for m in (None, mask):
        flat = optical_vignetting(same, render, mask=m, border=2)
        assert abs(flat.at(0.5) - 1) < 0.02 and abs(flat.at(0.9) - 1) < 0.03
    centre = np.zeros((h, w), bool)
    centre[20:-20, 20:-20] = True  # other rings than the whole image's
    with pytest.raises(ValueError, match="same mask"):
        vignetting_from_profiles(radial_profile(linear_luminance(real), centre),
                                 radial_profile(linear_luminance(render)))


def test_default_vignetting_is_flat_and_costs_nothing():
    """The defaults add no optical vignetting (settings.py: the render's light has the fall-off already)."""
    lin, _ = _synthetic_view(32, 48)
    opts = SensorOptions(noise=False).validated()
    assert sensor_vignetting(opts, 48, 32) is None
    assert sensor_vignetting(SensorOptions(vignetting_k1=-0.5).validated(), 48, 32) is not None
    off = SensorOptions(noise=False, vignetting=False).validated()
    assert meter(lin, opts) == meter(lin, off)
    assert np.array_equal(develop(lin, 0, "left", opts, Exposure(1.0, 1.0)).rgb,
                          develop(lin, 0, "left", off, Exposure(1.0, 1.0)).rgb)


def test_estimators_on_the_real_hamlyn_frames(shared_samples):
    """The defaults' source figures (left eye tuned, right eye held out; see sensor/settings.py)."""
    from rgbd2scene.files.images import read_image

    folder = shared_samples / HAMLYN
    left, right = (read_image(folder / f"f7_dynamic_deint_{e}_0100.png") for e in "LR")
    opts = SensorOptions()
    for img, tol in ((left, 0.02), (right, 0.15)):
        assert brightness_stats(img).trimmed_mean == pytest.approx(opts.target, rel=0.1 if tol > 0.1 else tol)
        a, b = fit_poisson_gaussian(noise_curve(img))
        assert a == pytest.approx(opts.noise_shot, rel=max(tol, 0.05) * 3)
        # the frame's whole fall-off (light and optics together; the sensor's default vignetting is only the
        # optics', flat: settings.py), as settings.py and benchmarks/results/sensor.md quote it
        fall = radial_falloff(img)
        assert fall.k1 == pytest.approx(REAL_FALLOFF_K1, rel=max(tol, 0.02))


def test_sensor_options_are_a_nested_record_of_the_render_options():
    import argparse

    from rgbd2scene.options import add_arguments, flag_of, from_args, from_mapping, resume_diff, to_record
    from rgbd2scene.stages.render import RenderOptions

    parser = argparse.ArgumentParser()
    add_arguments(parser, RenderOptions)
    args = parser.parse_args(["--samples", "2", "--no-noise", "--white-balance", "1,0.9,1.1", "--smoke", "30"])
    opts = from_args(RenderOptions, args).validated()
    assert opts.samples == 2 and opts.sensor.noise is False and opts.sensor.white_balance == (1.0, 0.9, 1.1)
    assert opts.environment.smoke == 30.0 and opts.sensor.exposure == "auto"
    # batch keys: a mapping; the record round-trips through the task file; errors name the dotted key
    mapped = from_mapping(RenderOptions, {"sensor": {"noise": False, "white_balance": "1,0.9,1.1"},
                                          "environment": {"smoke": 30}, "samples": 2}, "render").validated()
    assert mapped == opts
    record = to_record(opts)
    assert record["sensor"]["white_balance"] == [1.0, 0.9, 1.1]
    assert RenderOptions(**record).validated() == opts and resume_diff(opts, record) == []
    assert "sensor" in resume_diff(RenderOptions().validated(), record)
    with pytest.raises(OptionError) as err:
        RenderOptions(sensor=SensorOptions(ae_speed=2.0)).validated()
    assert err.value.name == "sensor.ae_speed" and flag_of(RenderOptions, err.value.name) == "--ae-speed"
    with pytest.raises(OptionError, match="unknown key") as err:
        from_mapping(RenderOptions, {"sensor": {"bogus": 1}}, "render")
    assert err.value.name == "render.sensor.bogus"


def test_frame_developer_writes_records_first_and_takes_a_lens_step(tmp_path):
    from rgbd2scene.dataset import layout as ds
    from rgbd2scene.dataset.develop_frames import FrameDeveloper
    from rgbd2scene.environment import EnvironmentOptions

    K = np.array([[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]])
    rng = np.random.default_rng(6)
    frames = [{eye: (rng.random((24, 32, 3)) * 0.3).astype(np.float32) for eye in ("left", "right")}
              for _ in range(3)]
    seen = []

    def lens(linear, eye):
        seen.append(eye)
        return linear[:, ::-1]  # any resampling: here a mirror

    opts = SensorOptions(ae_window=2).validated()
    dev = FrameDeveloper(tmp_path, opts, EnvironmentOptions().validated(), 0, 25.0, K, lens=lens)
    for i, linear in enumerate(frames):
        record = dev.develop_frame(i, linear)
        assert ds.read_sensor_record(tmp_path, i) == record and ds.rgb_done(tmp_path, i)
    assert seen == ["left", "right"] * 3
    assert record["window"] == [1, 2]
    expected = smoothed_log_exposure([dev.metered[1], dev.metered[2]], opts)
    assert opts.light_min < record["light"] and record["gain"] < opts.gain_max  # neither at its limit
    assert np.log(record["total"]) == pytest.approx(expected, abs=1e-9)
    # a second developer (a resumed chunk) reads the metering from the records; a frame whose history
    # nobody recorded is refused
    again = FrameDeveloper(tmp_path, opts, EnvironmentOptions().validated(), 0, 25.0, K, lens=lens)
    assert again.missing_history(3) == [] and again.missing_history(6) == [5]
    assert again.missing_history(6, coming=[5]) == []
    with pytest.raises(RuntimeError, match="metering"):
        again.develop_frame(6, frames[0])
