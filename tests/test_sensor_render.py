"""The sensor model in the render: every RGB effect on leaves the ground truth byte-identical, the PNGs repeat
byte for byte (also when a later chunk is rendered first and recomputes the auto exposure), and the records.

One tiny textured plane (64x32, 4 frames), rendered through ``rgbd2scene render`` (CLI in-process).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rgbd2scene.dataset import layout as ds
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig
from rgbd2scene.sensor import SensorOptions
from rgbd2scene.sensor.estimate import trimmed_mean
from rgbd2scene.sensor.tone import luminance

bpy = pytest.importorskip("bpy")
pytest.importorskip("OpenEXR")

from rgbd2scene.cli import main  # noqa: E402
from rgbd2scene.stages.blender import BuildScene, Task, run_task  # noqa: E402
from tests.conftest import write_scene_files  # noqa: E402

FRAMES = 4
LIGHT = Light(power_w=0.35, offset=(0.0025, 0.0, 0.0), outlets=2, outlet_spacing=0.008)
ALL_EFFECTS = ["--smoke", "40", "--motion-blur", "0.5", "--focus-distance", "0.05", "--aperture-mm", "1",
               "--jpeg-quality", "60", "--chroma", "420", "--interlace", "--clean", "--white-balance", "1.1,1,0.9"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """A textured plane 5-7 cm away, tilted; the camera slides along x (so motion blur has something to do)."""
    folder = tmp_path_factory.mktemp("sensor_scene")
    rng = np.random.default_rng(0)
    texture = rng.integers(40, 220, (32, 32, 3), dtype=np.uint8)
    corners = np.array([(-0.05, -0.05, 0.05), (-0.05, 0.05, 0.05), (0.05, 0.05, 0.07), (0.05, -0.05, 0.07)])
    mesh = SimpleNamespace(vertices=corners, triangles=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                           uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32), texture=texture,
                           vertex_colors=np.full((4, 3), 128, np.uint8))
    poses = np.array([np.eye(4) for _ in range(FRAMES)])
    poses[:, 0, 3] = 0.002 * np.arange(FRAMES)
    desc = SceneDescription(StereoRig.parallel(Intrinsics(64, 32, 50.0, 50.0, 31.5, 15.5), 0.005),
                            CameraPath(poses, fps=25.0, kind="test"), LIGHT, [tissue_object("as_captured")])
    write_scene_files(folder, mesh, desc)
    run_task(Task(BuildScene(str(folder), desc.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": desc.to_dict(), "test": True}))
    return folder


def _render(scene: Path, out: Path, *flags: str) -> None:
    assert main(["render", str(scene), "-o", str(out), "--no-sheet", "--quiet", *flags]) == 0


def _files(root: Path, pattern: str) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.glob(pattern))}


def test_effects_leave_ground_truth_untouched_and_pngs_repeat(scene, tmp_path):
    ideal, full, again = tmp_path / "ideal", tmp_path / "full", tmp_path / "again"
    _render(scene, ideal, "--exposure", "fixed", "--no-noise", "--no-vignetting")
    _render(scene, full, *ALL_EFFECTS)
    # the same dataset again, the second chunk first: its auto exposure must meter frames 0-1 itself
    _render(scene, again, *ALL_EFFECTS, "--start", "2")
    _render(scene, again, *ALL_EFFECTS)

    gt_ideal, gt_full = _files(ideal, "*/gt/*.npz"), _files(full, "*/gt/*.npz")
    assert len(gt_ideal) == 2 * FRAMES and gt_ideal == gt_full  # byte-identical ground truth
    png_full = _files(full, "*/rgb*/*.png")
    assert len(png_full) == 4 * FRAMES and png_full == _files(again, "*/rgb*/*.png")
    assert _files(full, "sensor/*.json") == _files(again, "sensor/*.json")

    # the effects are there: the images differ from the ideal camera's, the clean ones are noise- and JPEG-free
    for f in range(FRAMES):
        plain, _ = ds.read_frame(ideal, "left", f, rgb=True)
        noisy, _ = ds.read_frame(full, "left", f, rgb=True)
        assert np.abs(plain.astype(int) - noisy.astype(int)).mean() > 5
    info = json.loads((full / "dataset.json").read_text())
    assert info["sensor"]["exposure"] == "auto" and info["sensor"]["jpeg_quality"] == 60
    assert info["environment"]["smoke"] == 40.0 and info["render"]["sensor"]["interlace"] is True
    assert info["layout"]["sensor"] == "sensor/{frame:06d}.json"
    assert info["layout"]["rgb_clean"] == "{eye}/rgb_clean/{frame:06d}.png"


def test_auto_exposure_brings_the_frame_to_the_target(scene, tmp_path):
    out = tmp_path / "auto"
    _render(scene, out, "--clean", "--frames", "2")
    record = ds.read_sensor_record(out, 0)
    assert record["exposure_mode"] == "auto" and record["window"] == [0, 0]
    assert 0 < record["light"] <= 1 and 1 <= record["gain"] < SensorOptions().gain_max
    clean = np.asarray(__import__("cv2").imread(str(ds.clean_rgb_path(out, "left", 0)))[..., ::-1], float)
    assert trimmed_mean(luminance(clean)) == pytest.approx(SensorOptions().target, abs=1.5)
    print(f"frame 0: light {record['light']:.3f}, gain {record['gain']:.2f}")


def test_two_fibre_outlets_beside_the_lenses(scene):
    assert np.allclose(LIGHT.outlet_offsets(), [(-0.0015, 0.0, 0.0), (0.0065, 0.0, 0.0)], atol=1e-12)
    assert Light.from_dict(LIGHT.to_dict()) == LIGHT
    bpy.ops.wm.open_mainfile(filepath=str(scene / "scene.blend"))
    lamps = sorted((o for o in bpy.data.objects if o.type == "LIGHT"), key=lambda o: o.name)
    assert [o.name for o in lamps] == ["ScopeLight", "ScopeLight_2"]
    camera = bpy.data.objects["Endoscope"]
    for lamp, (x, y, z) in zip(lamps, LIGHT.outlet_offsets(), strict=True):
        assert lamp.parent == camera and lamp.data.energy == pytest.approx(0.175)
        assert tuple(lamp.location) == pytest.approx((x, -y, -z))  # OpenCV -> Blender camera axes
