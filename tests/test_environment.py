"""Environment effects: smoke's attenuation and airlight, its density field, ray lengths."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd2scene.environment import EnvironmentOptions, Smoke, active_effects, apply_environment, ray_length
from rgbd2scene.options import OptionError


def _scene(h=48, w=64):
    rng = np.random.default_rng(0)
    linear = (0.05 + 0.4 * rng.random((h, w, 3))).astype(np.float32)
    distance = np.linspace(0.03, 0.09, w, dtype=np.float32)[None, :].repeat(h, axis=0)
    return linear, distance


def _smoke(density, **kw):
    return Smoke.from_options(EnvironmentOptions(smoke=density, **kw).validated(), seed=3)


def test_smoke_reduces_contrast_monotonically_with_density():
    linear, distance = _scene()
    contrasts = [np.std(_smoke(d).apply(linear, distance, 0.5)) / np.mean(_smoke(d).apply(linear, distance, 0.5))
                 for d in (0.0, 5.0, 20.0, 60.0, 200.0)]
    assert np.all(np.diff(contrasts) < 0)
    assert contrasts[-1] < 0.1 * contrasts[0]


def test_dense_smoke_turns_to_its_colour_and_none_changes_nothing():
    linear, distance = _scene()
    assert np.array_equal(_smoke(0.0).apply(linear, distance, 0.0), linear)
    assert active_effects(EnvironmentOptions(), 0) == []
    thick = _smoke(5000.0, smoke_color=(1.0, 0.5, 0.25), smoke_variation=0.0).apply(linear, distance, 0.0)
    ratio = thick[..., 1] / thick[..., 0]
    assert np.allclose(ratio, 0.5, atol=1e-3)


def test_farther_surfaces_lose_more():
    linear = np.full((8, 2, 3), 0.5, np.float32)
    linear[:, 1] = 0.2  # a darker column sets a lower airlight than the bright one under smoke
    distance = np.full((8, 2), 0.03, np.float32)
    near = _smoke(30.0, smoke_variation=0.0).apply(linear, distance, 0.0)
    far = _smoke(30.0, smoke_variation=0.0).apply(linear, distance * 3, 0.0)
    assert abs(far[0, 0, 0] - far[0, 1, 0]) < abs(near[0, 0, 0] - near[0, 1, 0])


def test_density_field_is_seeded_smooth_and_drifts():
    smoke = _smoke(40.0)
    a = smoke.density_field(64, 48, 1.0)
    assert np.array_equal(a, _smoke(40.0).density_field(64, 48, 1.0))
    other = Smoke.from_options(EnvironmentOptions(smoke=40.0).validated(), seed=4).density_field(64, 48, 1.0)
    assert not np.array_equal(a, other)
    assert a.min() >= 0 and a.mean() == pytest.approx(40.0, rel=0.35)
    # smooth in space: neighbouring pixels differ far less than the field varies
    assert np.abs(np.diff(a, axis=1)).max() < 0.2 * (a.max() - a.min())
    # smooth in time: a frame later (1/30 s) it has moved a little, a few seconds later a lot
    step = np.abs(smoke.density_field(64, 48, 1.0 + 1 / 30) - a).mean()
    later = np.abs(smoke.density_field(64, 48, 4.0) - a).mean()
    assert 0 < step < 0.2 * later


def test_ray_length_is_the_distance_to_the_back_projected_point():
    K = np.array([[50.0, 0, 31.5], [0, 40.0, 23.5], [0, 0, 1]])
    depth = np.full((48, 64), 0.05)
    d = ray_length(depth, K)
    v, u = 10, 60
    point = np.array([(u - K[0, 2]) * 0.05 / K[0, 0], (v - K[1, 2]) * 0.05 / K[1, 1], 0.05])
    assert d[v, u] == pytest.approx(np.linalg.norm(point), rel=1e-12)
    assert d[24, 32] == pytest.approx(0.05 * np.sqrt(1 + (0.5 / 50) ** 2 + (0.5 / 40) ** 2))


def test_apply_environment_and_options():
    linear, distance = _scene()
    effects = active_effects(EnvironmentOptions(smoke=10.0).validated(), 1)
    out = apply_environment(linear, distance, 0.0, effects)
    assert out.shape == linear.shape and not np.array_equal(out, linear)
    with pytest.raises(OptionError):
        EnvironmentOptions(smoke=-1.0).validated()


def test_smoke_from_the_scene_configuration_and_the_render_switch(tmp_path):
    from rgbd2scene.geometry.camera import Intrinsics
    from rgbd2scene.scene.config import ConfigError, parse_scene_config
    from rgbd2scene.scene.model import SceneDescription
    from rgbd2scene.scene.paths import CameraPath
    from rgbd2scene.scene.rig import StereoRig
    from rgbd2scene.stages.render import RenderOptions, scene_environment

    config = parse_scene_config({"environment": {"smoke": 30, "smoke_color": [0.9, 0.8, 0.8]}}, tmp_path)
    assert config.environment == {"smoke": 30.0, "smoke_color": (0.9, 0.8, 0.8)}
    with pytest.raises(ConfigError, match="environment.smoke"):
        parse_scene_config({"environment": {"smoke": -3}}, tmp_path)
    with pytest.raises(ConfigError, match="environment"):
        parse_scene_config({"environment": {"fog": 1}}, tmp_path)
    desc = SceneDescription(StereoRig.parallel(Intrinsics(64, 32, 50.0, 50.0, 31.5, 15.5)),
                            CameraPath(np.eye(4)[None], fps=25.0, kind="test"), environment=config.environment)
    again = SceneDescription.from_dict(desc.to_dict())
    assert again.environment["smoke"] == 30.0
    # the scene's smoke unless the render sets its own
    assert scene_environment(RenderOptions().validated(), again).environment.smoke == 30.0
    own = RenderOptions(environment=EnvironmentOptions(smoke=5.0)).validated()
    assert scene_environment(own, again).environment.smoke == 5.0
    plain = SceneDescription(desc.rig, desc.path)
    assert "environment" not in plain.to_dict()
    assert scene_environment(RenderOptions().validated(), plain).environment.smoke == 0.0
