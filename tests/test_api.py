"""The newcomer's Python API (``rgbd2scene.api``): one call per command, the command's options as keywords, the
same files as the command line, keyword-named errors."""

import json
import subprocess
import sys
from dataclasses import dataclass, field

import numpy as np
import pytest

from rgbd2scene import api
from rgbd2scene.cli import main
from rgbd2scene.errors import UserError
from rgbd2scene.options import OptionError, option
from tests.conftest import BUNDLED_SAMPLE

CAPTURE = {"rgb": BUNDLED_SAMPLE / "rgb.png", "depth": BUNDLED_SAMPLE / "depth.png",
           "camera": BUNDLED_SAMPLE / "camera.json"}
CAPTURE_ARGS = ["--rgb", str(CAPTURE["rgb"]), "--depth", str(CAPTURE["depth"]), "--camera", str(CAPTURE["camera"])]


def _without_timings(record):
    """A scene.json record without its measured times (``timings``, ``..._seconds``, ``seconds``)."""
    if isinstance(record, dict):
        return {k: _without_timings(v) for k, v in record.items() if k != "timings" and not k.endswith("seconds")}
    return record


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A mesh folder, a scene (2 frames, 64x32) and its rendered dataset, each made by one API call."""
    root = tmp_path_factory.mktemp("api")
    mesh = api.mesh(root / "mesh", **CAPTURE, overview=False)
    scene = api.scene(root / "scene", mesh_dir=root / "mesh", frames=2, size="64x32", path="scan")
    render = api.render(root / "scene", root / "dataset", samples=2, gt="all", progress=False)
    return root, mesh, scene, render


def test_import_is_cheap():
    code = ("import sys, rgbd2scene.api; heavy = {'numpy', 'cv2', 'open3d', 'bpy', 'pydantic', 'scipy'}; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_mesh_gives_the_same_files_as_the_command(built, tmp_path):
    root, mesh, _, _ = built
    assert mesh.folder == root / "mesh" and mesh.mesh == root / "mesh" / "mesh.ply"
    on_disk = json.loads((root / "mesh" / "scene.json").read_text())
    assert on_disk == json.loads(json.dumps(mesh.record))  # the result's record is the one written
    assert not (root / "mesh" / "overview.png").exists()  # overview=False is --no-overview
    assert main(["mesh", *CAPTURE_ARGS, "--no-overview", "-o", str(tmp_path / "cli")]) == 0
    assert (tmp_path / "cli" / "mesh.ply").read_bytes() == mesh.mesh.read_bytes()
    cli_record = json.loads((tmp_path / "cli" / "scene.json").read_text())
    assert _without_timings(cli_record) == _without_timings(on_disk)


def test_scene_gives_the_same_record_as_the_command(built, tmp_path):
    root, _, scene, _ = built
    assert scene.blend == root / "scene" / "scene.blend" and scene.blend.is_file()
    assert scene.record["scene"]["path"]["frames"] == 2
    assert scene.record["scene_options"]["size"] == [64, 32]  # "64x32" parsed as on the command line
    assert main(["scene", "--mesh-dir", str(root / "mesh"), "--frames", "2", "--size", "64x32", "--path", "scan",
                 "-o", str(tmp_path / "cli")]) == 0
    cli_record = json.loads((tmp_path / "cli" / "scene.json").read_text())
    api_record = json.loads((root / "scene" / "scene.json").read_text())
    assert _without_timings(cli_record) == _without_timings(api_record)


def test_render_writes_the_dataset_with_its_options(built):
    root, _, _, render = built
    assert render.dataset == root / "dataset" and (render.rendered, render.skipped) == (2, 0)
    assert render.sheet == root / "dataset" / "contact_sheet.png" and render.sheet.is_file()
    info = json.loads((root / "dataset" / "dataset.json").read_text())
    assert (info["width"], info["height"], info["frames"]) == (64, 32, 2)
    assert info["render"]["samples"] == 2
    for eye in ("left", "right"):
        gt = np.load(root / "dataset" / eye / "gt" / "000001.npz")
        assert gt["depth"].shape == (32, 64) and np.isfinite(gt["depth"]).mean() > 0.5
    again = api.render(root / "scene", root / "dataset", samples=2, progress=False, sheet=False)
    assert (again.rendered, again.skipped, again.sheet) == (0, 2, None)  # resumed: nothing left to do


def test_verify_passes_and_writes_its_json(built, tmp_path):
    root = built[0]
    report = api.verify(root / "dataset", json=tmp_path / "report.json", progress=False)
    assert report.ok
    assert json.loads((tmp_path / "report.json").read_text())["ok"] is True


def test_export_writes_the_files_it_counts(built, tmp_path):
    summary = api.export(built[0] / "dataset", "kitti", tmp_path / "kitti", progress=False)
    assert summary.frames == 2
    assert summary.files == sum(1 for p in (tmp_path / "kitti").rglob("*") if p.is_file())
    with pytest.raises(OptionError, match="^format: choose one of kitti, sceneflow, visionblender"):
        api.export(built[0] / "dataset", "middlebury", tmp_path / "other")


def test_export_ros_writes_a_bag(built, tmp_path):
    summary = api.export_ros(built[0] / "dataset", tmp_path / "bag", ros=2, rate=10.0, progress=False)
    assert summary.out == tmp_path / "bag" and (tmp_path / "bag" / "metadata.yaml").is_file()
    with pytest.raises(OptionError, match=r"export-ros: rate must be a positive number .*\(ros, rate, start\)"):
        api.export_ros(built[0] / "dataset", tmp_path / "bag2", rate=-1.0)


def test_evaluate_scores_the_ground_truth_as_exact(built, tmp_path):
    result = api.evaluate(built[0] / "dataset", tmp_path / "eval", methods="gt", error_maps=False, progress=False)
    rows = [r for r in result.rows if r.method == "gt" and r.scored == "all"]
    assert rows and rows[0].frames == 2
    assert rows[0].values["rmse_mm"][0] < 1e-3
    assert (tmp_path / "eval" / "metrics.csv").is_file()


def test_realism_of_a_frame_against_itself_is_one(built, tmp_path):
    root = built[0]
    result = api.realism(root / "dataset", root / "dataset" / "left" / "rgb" / "000000.png", tmp_path / "realism",
                         methods="none")
    assert result.picture.is_file() and result.markdown.is_file()
    ratios = [r.ratio for r in result.report.rows if np.isfinite(r.ratio)]
    assert ratios and np.allclose(ratios, 1.0)


def test_dataset_builds_a_sequence_from_a_scene_folder(built, tmp_path):
    config = tmp_path / "build.yaml"
    config.write_text(f"seed: 0\ncaptures:\n  - name: t\n    scene: {built[0] / 'scene'}\n"
                      "sequences:\n  per_capture: 1\n  frames: 2\n  paths: [scan]\nrender:\n  size: 64x32\n")
    summary = api.dataset(config, tmp_path / "root", jobs=1, progress=False)
    assert summary.count("done") == 1 and not summary.failed
    assert (tmp_path / "root" / "manifest.csv").is_file()


def test_unknown_keywords_are_type_errors_naming_them(tmp_path):
    with pytest.raises(TypeError, match="render\\(\\) got an unexpected keyword argument 'sampels'"):
        api.render(tmp_path, tmp_path / "d", sampels=4)
    with pytest.raises(TypeError, match="'fov'"):  # the flag is --fov, the keyword its field fov_x_deg
        api.scene(tmp_path / "s", **CAPTURE, fov=60)
    with pytest.raises(TypeError, match="'qiet'"):
        api.verify(tmp_path, qiet=True)
    with pytest.raises(TypeError, match="'workrs'"):
        api.dataset(tmp_path / "c.yaml", tmp_path / "r", workrs=2)


@pytest.mark.parametrize("call, message", [
    (lambda d, s: api.render(s, d / "out", denoise="magic"), "denoise: choose one of none, oidn, optix"),
    (lambda d, s: api.render(s, d / "out", frames="many"), "frames: "),
    (lambda d, s: api.render(s, d / "out", size="64by32"), "size: size must look like 512x256"),
    (lambda d, s: api.scene(d / "out", mesh_dir=d, baseline=0.5), "baseline: 0.5 m is not a plausible"),
    (lambda d, s: api.scene(d / "out", mesh_dir=d, path="spiral"), "path: choose one of"),
    (lambda d, s: api.mesh(d / "out", **CAPTURE, depth_range=(0.1, 0.5)),
     "depth_range do(es) not apply to a single RGB-D frame"),
    (lambda d, s: api.mesh(d / "out", rgb=CAPTURE["rgb"]), "give rgb and depth"),
    (lambda d, s: api.scene(d / "out"), "scene: give a capture (rgb and depth, or left, right and stereo_calib) "
                                        "or mesh_dir"),
    (lambda d, s: api.evaluate(d, min_depth=0.1), "evaluate: give both min_depth and max_depth, or neither"),
    (lambda d, s: api.realism(d, [d / "a.png"] * 3), "realism: real takes the LEFT image"),
])
def test_bad_values_are_option_errors_naming_the_keyword(tmp_path, call, message):
    scene = tmp_path / "scene"  # never read: the values are refused first
    with pytest.raises(OptionError) as info:
        call(tmp_path, scene)
    assert str(info.value).startswith(message) or message in str(info.value), str(info.value)
    assert "--" not in str(info.value)
    assert not (tmp_path / "out").exists()


def test_the_command_names_the_flag_of_the_same_error(tmp_path, capsys):
    assert main(["evaluate", str(tmp_path), "--min-depth", "0.1"]) == 2
    assert capsys.readouterr().err.strip() == "error: evaluate: give both --min-depth and --max-depth, or neither"
    assert main(["scene", "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == ("error: scene: give a capture (--rgb and --depth, or --left, --right "
                                               "and --stereo-calib) or --mesh-dir (a mesh folder)")


def test_missing_files_are_user_errors(tmp_path):
    with pytest.raises(UserError, match="scene folder not found"):
        api.render(tmp_path / "nope", tmp_path / "d")


@dataclass
class _Sensor:
    noise: bool = option(True, "no noise")
    gain: float = option(1.0, "gain")


@dataclass
class _Stage:
    samples: int = option(1, "samples")
    sensor: _Sensor = field(default_factory=_Sensor)  # a nested record, as the render's sensor settings


def test_a_nested_records_fields_are_keywords_as_they_are_flags():
    (stage,) = api._options("toy", {"samples": 2, "noise": False, "gain": "2.5"}, _Stage)
    assert stage == _Stage(samples=2, sensor=_Sensor(noise=False, gain=2.5))
    (stage,) = api._options("toy", {"sensor": {"gain": 3.0}, "noise": False}, _Stage)  # the record's own name
    assert stage.sensor == _Sensor(noise=False, gain=3.0)
    with pytest.raises(TypeError, match="'nois'"):
        api._options("toy", {"nois": False}, _Stage)
    with pytest.raises(OptionError) as info:
        api._options("toy", {"gain": "bright"}, _Stage)
    assert info.value.name.startswith("sensor")  # the record (or its field, sensor.gain)
