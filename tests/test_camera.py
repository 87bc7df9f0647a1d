import json

import numpy as np
import pytest

from rgbd2scene.capture.camera import PRESETS, load_camera_json, preset
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.options import OptionError


def test_plain_and_open3d_json_forms_agree(tmp_path):
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"width": 640, "height": 480, "fx": 525, "fy": 520, "cx": 319.5, "cy": 239.5,
                                 "depth_scale": 5000}))
    o3d_form = tmp_path / "o3d.json"
    K = np.array([[525, 0, 319.5], [0, 520, 239.5], [0, 0, 1.0]])
    o3d_form.write_text(json.dumps({"width": 640, "height": 480, "intrinsic_matrix": K.T.ravel().tolist()}))
    a, scale_a = load_camera_json(plain)
    b, scale_b = load_camera_json(o3d_form)
    assert a == b and scale_a == 5000 and scale_b is None
    assert np.allclose(a.K, K)


def test_presets():
    assert preset("primesense") == Intrinsics(640, 480, 525, 525, 319.5, 239.5)
    assert {"tum_fr1", "tum_fr2", "tum_fr3"} <= set(PRESETS)
    with pytest.raises(OptionError, match="unknown camera preset") as info:
        preset("nope")
    assert info.value.name == "preset"  # the CLI spells it --preset, a batch configuration preset


@pytest.mark.parametrize(
    "content, message",
    [
        ("{", "not a readable JSON"),
        ('{"width": 640, "height": 480}', "lacks key"),
        ('{"width": 640, "height": 480, "fx": -5, "fy": 5, "cx": 3, "cy": 3}', "focal lengths must be positive"),
        ('{"width": 640, "height": 480, "fx": 525, "fy": 525, "cx": 900, "cy": 3}', "principal point"),
        ('{"width": 640, "height": 480, "intrinsic_matrix": [1, 2]}', "9 numbers"),
    ],
)
def test_bad_camera_json(tmp_path, content, message):
    path = tmp_path / "cam.json"
    path.write_text(content)
    with pytest.raises(UserError, match=message) as info:
        load_camera_json(path)
    assert str(path) in str(info.value)


def test_resized_keeps_pixel_centre_convention():
    intr = Intrinsics.from_fov(640, 480, 60.0)
    half = intr.resized(320, 240)
    assert half.cx == pytest.approx((320 - 1) / 2) and half.cy == pytest.approx((240 - 1) / 2)
    assert half.fx == pytest.approx(intr.fx / 2)
