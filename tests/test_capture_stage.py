"""The capture stage (``rgbd2scene.stages.capture``): options declared once, the same errors on the command line
and in batch configurations for every kind of capture (single, fused, stereo), bad input of the new input paths,
and the depth sensor inferred from the capture."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rgbd2scene.batch.config import load_config
from rgbd2scene.capture.sensors import KINECT_V1, SENSORS, infer_sensor
from rgbd2scene.cli import main
from rgbd2scene.errors import UserError
from rgbd2scene.options import OptionError, add_arguments, flag_of, from_args, from_mapping
from rgbd2scene.stages.capture import CaptureOptions, check_inputs, load_inputs
from tests.conftest import BUNDLED_SAMPLE, SHARED_SAMPLES

HAMLYN = SHARED_SAMPLES / "hamlyn_silicone_heart_phantom_stereo"
REDWOOD = SHARED_SAMPLES / "redwood_livingroom1_5frames_open3d"


# --------------------------------------------------------------------------------------------- options


def test_two_value_and_list_fields_from_flags_and_configuration_keys():
    parser = argparse.ArgumentParser()
    add_arguments(parser, CaptureOptions)
    args = parser.parse_args(["--depth-range", "0.03", "0.2", "--rgb", "a.png", "b.png", "--depth", "a.png", "b.png"])
    options = from_args(CaptureOptions, args)
    assert options.depth_range == (0.03, 0.2) and options.rgb == ["a.png", "b.png"]
    with pytest.raises(SystemExit):
        parser.parse_args(["--depth-range", "0.03"])
    mapped = from_mapping(CaptureOptions, {"depth_range": [0.03, 0.2], "rgb": ["a.png", "b.png"], "poses": "t.txt"},
                          base_dir="/base")
    assert mapped.depth_range == (0.03, 0.2)
    assert mapped.rgb == ["/base/a.png", "/base/b.png"] and mapped.poses == "/base/t.txt"
    for bad in ([0.03], [0.03, 0.2, 0.5], ["near", "far"]):
        with pytest.raises(OptionError) as info:
            from_mapping(CaptureOptions, {"depth_range": bad}, "captures[0]")
        assert info.value.name == "captures[0].depth_range"
    assert flag_of(CaptureOptions, "stereo_calib") == "--stereo-calib"


def test_option_errors_are_spelled_by_each_front_end():
    sentence = OptionError("depth", "{rgb} has 2 files but {depth} has 1")
    assert sentence.render(lambda name: "--" + name.replace("_", "-")) == "--rgb has 2 files but --depth has 1"
    assert sentence.render(where="captures[3]") == "captures[3]: rgb has 2 files but depth has 1"
    plain = OptionError("voxel_size", "must be positive, got {uniform: [lo, hi]}")  # braces of a value stay
    assert plain.render(lambda name: "--voxel-size") == "--voxel-size: must be positive, got {uniform: [lo, hi]}"
    assert plain.render(where="captures[0]") == "captures[0].voxel_size: must be positive, got {uniform: [lo, hi]}"


# --------------------------------------------------------------------------------------------- inputs


def _calibration(**changes) -> dict:
    calib = {"K_left": [[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]], "D_left": [0, 0, 0, 0, 0],
             "K_right": [[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]], "D_right": [0, 0, 0, 0, 0],
             "R": np.eye(3).tolist(), "T": [-0.005, 0, 0], "image_size": [64, 48]}
    calib.update(changes)
    return {k: v for k, v in calib.items() if v is not None}


@pytest.fixture
def inputs(tmp_path) -> Path:
    """A stereo pair of 64x48 images with calibrations, and three 64x48 RGB-D frames (mm PNG and npy depth,
    0.6-0.7 m) with their camera and trajectories."""
    rng = np.random.default_rng(3)
    for name in ("left.png", "right.png"):
        cv2.imwrite(str(tmp_path / name), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    cv2.imwrite(str(tmp_path / "small.png"), rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))
    (tmp_path / "calib.json").write_text(json.dumps(_calibration()))
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"rgb{k}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
        depth = np.full((48, 64), 0.6 + 0.05 * k, np.float32)
        cv2.imwrite(str(tmp_path / f"depth{k}.png"), np.round(depth * 1000).astype(np.uint16))
        np.save(tmp_path / f"depth{k}.npy", depth)
    depth[5, 7] = np.nan
    np.save(tmp_path / "depth_nan.npy", depth)
    (tmp_path / "camera.json").write_text(json.dumps({"width": 64, "height": 48, "fx": 60.0, "fy": 60.0,
                                                      "cx": 31.5, "cy": 23.5}))
    tum = "".join(f"{t}.0 0 0 {0.01 * t} 0 0 0 1\n" for t in range(3))
    (tmp_path / "traj.txt").write_text(tum)
    (tmp_path / "traj_short.txt").write_text("".join(tum.splitlines(keepends=True)[:2]))
    (tmp_path / "traj_nan.txt").write_text(tum.replace("2.0 0 0 0.02", "2.0 0 nan 0.02"))
    block = "{k} {k} {k}\n{r0}\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"
    (tmp_path / "traj.log").write_text("".join(block.format(k=k, r0="1 0 0 0" if k < 2 else "2 0 0 0")
                                               for k in range(3)))
    return tmp_path


STEREO = {"left": "left.png", "right": "right.png", "stereo_calib": "calib.json"}
FUSED = {"rgb": ["rgb0.png", "rgb1.png", "rgb2.png"], "depth": ["depth0.png", "depth1.png", "depth2.png"],
         "camera": "camera.json"}

#: case -> (capture keys, calibration changes or None, what the message says, spelled for the CLI and for a
#: configuration: the field of the error, and the file it names, if any)
CASES = {
    "stereo_missing_key": ({"left": "left.png", "stereo_calib": "calib.json"}, None,
                           "a stereo frame needs {left}, {right} and {stereo_calib} (missing {right})", None),
    "stereo_and_rgbd": ({**STEREO, "rgb": ["rgb0.png"], "depth": ["depth0.png"]}, None, "not both", None),
    "stereo_with_fusion_key": ({**STEREO, "voxel_size": 0.001}, None,
                               "{voxel_size} do(es) not apply to a stereo frame", None),
    "stereo_with_camera": ({**STEREO, "camera": "camera.json"}, None,
                           "{camera} do(es) not apply to a stereo frame", None),
    "calib_missing_key": (STEREO, {"R": None}, "{stereo_calib}: <calib.json>: bad stereo calibration: missing key(s) R",
                          "calib.json"),
    "calib_extra_key": (STEREO, {"K_lft": [1, 2, 3]}, "bad stereo calibration: unknown key(s) K_lft", "calib.json"),
    "calib_wrong_matrix_size": (STEREO, {"K_left": [[60.0, 0, 31.5], [0, 60.0, 23.5]]},
                                "K_left must have 9 numbers (3x3), got 6", "calib.json"),
    "calib_wrong_distortion_size": (STEREO, {"D_right": [0.1] * 6}, "D_right has 6 coefficients", "calib.json"),
    "calib_wrong_image_size": ({**STEREO, "left": "small.png", "right": "small.png"}, None,
                               "the images are 32x24 but the calibration", "calib.json"),
    "calib_not_a_rotation": (STEREO, {"R": [[1, 0, 0], [0, 1, 0.2], [0, 0, 1]]}, "R is not a rotation",
                             "calib.json"),
    "calib_nan": (STEREO, {"T": [float("nan"), 0, 0]}, "T contains non-finite values", "calib.json"),
    "calib_nan_intrinsics": (STEREO, {"K_right": [[float("nan"), 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]]},
                             "K_right contains non-finite values", "calib.json"),
    "fused_counts": ({**FUSED, "depth": FUSED["depth"][:2]}, None, "{rgb} has 3 files but {depth} has 2", None),
    "fused_trajectory_short": ({**FUSED, "poses": "traj_short.txt"}, None,
                               "{poses}: <traj_short.txt>: 2 poses for 3 frames", "traj_short.txt"),
    "fused_trajectory_not_rotation": ({**FUSED, "poses": "traj.log"}, None, "the 3x3 part is not a rotation",
                                      "traj.log"),
    "fused_trajectory_nan": ({**FUSED, "poses": "traj_nan.txt"}, None, "line 3: non-finite value", "traj_nan.txt"),
    "fused_trajectory_missing": ({**FUSED, "poses": "nope.txt"}, None, "{poses}: <nope.txt>: ", "nope.txt"),
    "fused_stereo_key": ({**FUSED, "depth_range": [0.1, 0.5]}, None,
                         "{depth_range} do(es) not apply to fused RGB-D frames", None),
    "fused_bad_voxel": ({**FUSED, "voxel_size": -0.01}, None, "{voxel_size}: must be a positive number of metres",
                        None),
    "single_with_poses": ({"rgb": ["rgb0.png"], "depth": ["depth0.png"], "poses": "traj.txt"}, None,
                          "{poses} needs several frames", None),
}


def _write_case(folder: Path, case: str) -> dict:
    keys, calib, _, _ = CASES[case]
    if calib is not None:
        (folder / "calib.json").write_text(json.dumps(_calibration(**calib)))
    return keys


def _cli_args(folder: Path, keys: dict) -> list[str]:
    args = []
    for name, value in keys.items():
        values = value if isinstance(value, list) else [value]
        paths = [str(folder / v) if isinstance(v, str) else str(v) for v in values]
        args += [flag_of(CaptureOptions, name), *paths]
    return args


def _expected(case: str, folder: Path, spell) -> str:
    """The message of ``case`` with its fields spelled by ``spell`` and ``<file>`` as the file's full path."""
    _, _, message, _ = CASES[case]
    for name in ("left", "right", "stereo_calib", "rgb", "depth", "poses", "camera", "voxel_size", "depth_range"):
        message = message.replace(f"{{{name}}}", spell(name))
    return message.replace("<", str(folder) + "/").replace(">", "")


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_on_the_command_line_is_one_line_naming_the_flag_and_the_file(inputs, capsys, case):
    keys = _write_case(inputs, case)
    out = inputs / "out"
    assert main(["mesh", *_cli_args(inputs, keys), "-o", str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert _expected(case, inputs, lambda name: flag_of(CaptureOptions, name)) in lines[0], lines[0]
    file = CASES[case][3]
    if file:
        assert str(inputs / file) in lines[0]
    assert not out.exists()  # found before anything is written


def _batch(folder: Path, entry: dict) -> Path:
    config = {"seed": 0, "captures": [{"name": "c", **entry}], "sequences": {"frames": 2}, "render": {"size": "64x32"}}
    path = folder / "batch.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_in_a_batch_entry_is_the_same_error_naming_the_key(inputs, capsys, case):
    keys = _write_case(inputs, case)
    config = _batch(inputs, keys)
    root = inputs / "root"
    assert main(["dataset", str(config), "-o", str(root), "--quiet"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {config}: captures[0]"), lines
    assert _expected(case, inputs, str) in lines[0], lines[0]
    if CASES[case][3]:
        assert str(inputs / CASES[case][3]) in lines[0]
    assert not root.exists()


@pytest.mark.parametrize("entry, message", [
    ({**STEREO, "rigth": "right.png"}, "captures[0].rigth: unknown key (known: name, scene, mesh, split, rgb, depth"),
    ({**STEREO, "left": ["left.png"]}, "captures[0].left: give a file path, got ['left.png']"),
    ({**STEREO, "depth_range": 0.2}, "captures[0].depth_range: "),
    ({**STEREO, "scene": "elsewhere"}, "captures[0]: give either a capture (left, right, stereo_calib) or a scene"),
    ({"right": "right.png"}, "captures[0]: a stereo frame needs left, right and stereo_calib (missing left and "
                             "stereo_calib)"),
    ({**FUSED, "rgb": ["rgb*.png"], "depth": ["nope*.png"]}, "captures[0].depth[0]: no file matches"),
])
def test_batch_entry_keys_are_checked(inputs, capsys, entry, message):
    config = _batch(inputs, entry)
    with pytest.raises(UserError) as info:
        load_config(config)
    assert f"{config}: {message}" in str(info.value), str(info.value)


def test_nan_depth_in_a_fused_frame_is_refused_naming_the_file(inputs, capsys):
    """Depth is read when the capture is loaded: on the command line before anything is written; in a batch
    build the capture's sequences fail with the entry and the file named."""
    depth = [str(inputs / name) for name in ("depth0.npy", "depth_nan.npy", "depth2.npy")]
    rgb = [str(inputs / f"rgb{k}.png") for k in range(3)]
    out = inputs / "out"
    assert main(["mesh", "--rgb", *rgb, "--depth", *depth, "--camera", str(inputs / "camera.json"),
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    nan_file = inputs / "depth_nan.npy"
    assert err == f"error: {nan_file}: depth contains NaN or infinite values (write 0 for missing depth)"
    assert not out.exists()
    from rgbd2scene.batch.tasks import build_mesh

    capture = load_config(_batch(inputs, {"rgb": rgb, "depth": depth, "camera": "camera.json"})).captures[0]
    outcome = build_mesh(capture, str(inputs / "mesh"))
    assert not outcome.ok and outcome.error.startswith(f"captures[0]: {inputs / 'depth_nan.npy'}: depth contains NaN")
    assert not (inputs / "mesh" / "scene.json").exists()


def test_batch_entries_mean_what_the_flags_mean(inputs):
    """A fused entry (a glob in a list) and a stereo entry give the capture options of the same flags."""
    config = load_config(_batch(inputs, {"rgb": ["rgb*.png"], "depth": ["depth?.png"], "poses": "traj.txt",
                                         "camera": "camera.json", "voxel_size": 0.002}))
    parser = argparse.ArgumentParser()
    add_arguments(parser, CaptureOptions)
    flags = from_args(CaptureOptions, parser.parse_args(_cli_args(inputs, {**FUSED, "poses": "traj.txt",
                                                                           "voxel_size": 0.002})))
    assert config.captures[0].inputs == flags
    assert config.captures[0].record()["rgb"] == [str(inputs / f"rgb{k}.png") for k in range(3)]
    stereo = load_config(_batch(inputs, {**STEREO, "depth_range": [0.02, 0.2], "matcher": "sgbm"})).captures[0]
    assert check_inputs(stereo.inputs) == "stereo"
    assert stereo.inputs.stereo_options().min_depth == 0.02 and stereo.inputs.stereo_options().matcher == "sgbm"


@pytest.fixture(scope="module")
def hamlyn_cli_mesh(tmp_path_factory):
    if not HAMLYN.is_dir():
        pytest.skip(f"real captures not available: {HAMLYN} is absent")
    out = tmp_path_factory.mktemp("hamlyn") / "mesh"
    assert main(["mesh", "--left", str(HAMLYN / "f7_dynamic_deint_L_0100.png"), "--right",
                 str(HAMLYN / "f7_dynamic_deint_R_0100.png"), "--stereo-calib", str(HAMLYN), "--matcher", "sgbm",
                 "--no-overview", "-o", str(out)]) == 0
    return out


def test_batch_mesh_of_a_stereo_entry_equals_the_command_line_mesh(hamlyn_cli_mesh, tmp_path):
    from rgbd2scene.batch.tasks import build_mesh
    from rgbd2scene.files.meshio import read_ply

    config = _batch(tmp_path, {"left": str(HAMLYN / "*_L_0100.png"), "right": str(HAMLYN / "*_R_0100.png"),
                               "stereo_calib": str(HAMLYN), "matcher": "sgbm", "mesh": {"overview": False}})
    capture = load_config(config).captures[0]
    assert capture.name == "c_f7_dynamic_deint"
    outcome = build_mesh(capture, str(tmp_path / "mesh"))
    assert outcome.ok, outcome.log
    ours, theirs = read_ply(tmp_path / "mesh" / "mesh.ply"), read_ply(hamlyn_cli_mesh / "mesh.ply")
    assert np.array_equal(ours.vertices, theirs.vertices) and np.array_equal(ours.triangles, theirs.triangles)
    record = json.loads((tmp_path / "mesh" / "scene.json").read_text())
    assert record["depth_sensor"]["name"] == "none" and record["depth_sensor"]["source"] == "inferred"
    assert record["fill"]["settings"]["sensor"]["kind"] == "none"


def test_batch_mesh_of_a_fused_entry(tmp_path):
    if not REDWOOD.is_dir():
        pytest.skip(f"real captures not available: {REDWOOD} is absent")
    from rgbd2scene.batch.tasks import build_mesh

    config = _batch(tmp_path, {"rgb": [str(REDWOOD / "color" / "*.jpg")], "depth": [str(REDWOOD / "depth/*.png")],
                               "poses": str(REDWOOD / "trajectory.log"),
                               "camera": str(REDWOOD / "camera_primesense.json"), "depth_scale": 1000,
                               "mesh": {"overview": False}})
    capture = load_config(config).captures[0]
    assert len(capture.inputs.rgb) == 5
    assert build_mesh(capture, str(tmp_path / "mesh")).ok
    record = json.loads((tmp_path / "mesh" / "scene.json").read_text())
    assert len(record["fusion"]["frames"]) == 5 and record["fusion"]["poses"]["association"] == "order"
    assert record["depth_sensor"]["name"] == "none" and "fused" in record["depth_sensor"]["reason"]


# --------------------------------------------------------------------------------------------- sensor


def test_the_folder_prepared_while_the_mesh_is_built_is_the_folder_written_after_it(inputs, tmp_path):
    """``reconstruct_mesh_folder`` prepares the files that need no mesh on another thread once the depth is
    filled; every file must be the one ``write_mesh_folder`` writes from the finished reconstruction."""
    from rgbd2scene.pictures.overview import make_overview
    from rgbd2scene.reconstruct.pipeline import MeshOptions
    from rgbd2scene.stages.capture import reconstruct_inputs
    from rgbd2scene.stages.mesh import _overview_image, reconstruct_mesh_folder, write_mesh_folder

    depth = cv2.imread(str(inputs / "depth0.png"), cv2.IMREAD_UNCHANGED)
    depth[10:20, 30:40] = 0  # a hole to fill
    cv2.imwrite(str(tmp_path / "holey.png"), depth)
    loaded = load_inputs(CaptureOptions(rgb=[str(inputs / "rgb0.png")], depth=[str(tmp_path / "holey.png")],
                                        camera=str(inputs / "camera.json")))
    called = []
    recon, _ = reconstruct_mesh_folder(tmp_path / "early", loaded, MeshOptions(fill="biharmonic"))
    recon_after = reconstruct_inputs(loaded, MeshOptions(fill="biharmonic"), on_filled=lambda *a: called.append(a))
    assert len(called) == 1 and called[0][1].method == recon_after.filled.method
    write_mesh_folder(tmp_path / "after", recon_after)
    early, after = sorted((tmp_path / "early").iterdir()), sorted((tmp_path / "after").iterdir())
    assert [p.name for p in early] == [p.name for p in after]
    assert {"overview.png", "texture_original.png", "depth_filled.npy"} <= {p.name for p in early}
    for a, b in zip(early, after, strict=True):
        if a.name != "scene.json":  # its times differ
            assert a.read_bytes() == b.read_bytes(), a.name
    assert np.array_equal(recon.mesh.vertices, recon_after.mesh.vertices)
    # and the overview is the one drawn in one go from the finished reconstruction
    sheet = make_overview(recon.capture.rgb, recon.capture.depth, recon.filled.depth.astype(np.float32),
                          _overview_image(recon), title="rgb0.png")
    assert np.array_equal(cv2.imread(str(tmp_path / "early" / "overview.png"))[..., ::-1], sheet)


def test_sensor_inference_rules():
    room = np.full((48, 64), 2.0, np.float32)
    organ = np.full((48, 64), 0.08, np.float32)
    room[0, 0] = np.nan
    cases = [
        (dict(depth=room, depth_format="png"), "kinect_v1", "default"),
        (dict(depth=room, depth_format="png", named="kinect_v1"), "kinect_v1", "preset"),
        (dict(depth=room, depth_format="nyu"), "kinect_v1", "inferred"),
        (dict(depth=organ, depth_format="png"), "none", "inferred"),  # nearer than a Kinect v1 measures
        (dict(depth=organ, depth_format="png", named="kinect_v1"), "none", "inferred"),
        (dict(depth=room, depth_format="exr"), "none", "inferred"),  # CT or rendered depth
        (dict(depth=room, depth_format="npy"), "none", "inferred"),
        (dict(depth=room, depth_format="float"), "none", "inferred"),
        (dict(depth=organ, depth_format="stereo"), "none", "inferred"),
        (dict(depth=room, depth_format="png", fused=True), "none", "inferred"),
        (dict(depth=organ, depth_format="png", given="realsense"), "realsense", "given"),  # the user says so
        (dict(depth=room, depth_format="npy", given="kinect_v1"), "kinect_v1", "given"),
    ]
    for kwargs, name, source in cases:
        choice = infer_sensor(**kwargs)
        assert (choice.sensor.name, choice.source) == (name, source), (kwargs, choice)
        json.dumps(choice.to_dict())
    assert "working range 0.4-10 m" in infer_sensor(organ, "png").reason
    assert "note: 100 % of the valid depth lies outside" in infer_sensor(organ, "png", given="kinect_v1").reason
    # 1 % of the pixels nearer than 0.4 m (noise, a hand in view) does not rule the sensor out; 2 % does
    near = room.copy()
    near.flat[1:31] = 0.3  # 30 of 3071 valid pixels
    assert infer_sensor(near, "png").sensor is KINECT_V1
    near.flat[1:62] = 0.3
    assert infer_sensor(near, "png").sensor.name == "none"
    with pytest.raises(OptionError, match="unknown sensor 'sonar'"):
        infer_sensor(room, "png", given="sonar")


@pytest.fixture(scope="module")
def sample_meshes(tmp_path_factory):
    """The bundled Kinect-range sample as captured, and the same depth PNG read at 1/8 the scale (0.07-0.1 m:
    an organ at endoscopic range that no Kinect v1 could have measured), with and without --sensor."""
    root = tmp_path_factory.mktemp("sensor")
    base = ["mesh", "--rgb", str(BUNDLED_SAMPLE / "rgb.png"), "--depth", str(BUNDLED_SAMPLE / "depth.png"),
            "--camera", str(BUNDLED_SAMPLE / "camera.json"), "--no-overview", "--smooth", "none"]
    runs = {"room": [], "near": ["--depth-scale", "8000"], "near_given": ["--depth-scale", "8000", "--sensor",
                                                                            "kinect_v1"]}
    for name, extra in runs.items():
        assert main([*base, *extra, "-o", str(root / name)]) == 0
    return root


def test_near_depth_gets_no_projector_shadows_and_scene_json_says_why(sample_meshes):
    from rgbd2scene.capture.readers import read_depth, read_rgb
    from rgbd2scene.reconstruct.fill import fill_depth

    records = {name: json.loads((sample_meshes / name / "scene.json").read_text())
               for name in ("room", "near", "near_given")}
    assert records["room"]["depth_sensor"]["name"] == "kinect_v1"
    assert records["room"]["depth_sensor"]["source"] == "default"
    near = records["near"]["depth_sensor"]
    assert (near["name"], near["source"], near["casts_shadows"]) == ("none", "inferred", False)
    assert "outside the kinect_v1's working range 0.4-10 m" in near["reason"]
    assert records["near"]["options"]["sensor"] == "none"
    assert records["near"]["fill"]["settings"]["sensor"]["kind"] == "none"
    assert records["near_given"]["depth_sensor"]["source"] == "given"
    assert records["near_given"]["fill"]["settings"]["sensor"]["kind"] == "structured_light"
    # and whether the fill took the model's shadows from the capture, and why
    assert near["shadows"] == {"cast": False, "runs": 0, "direct_steps": -1,
                               "reason": "the sensor assumed casts no shadows"}
    for name in ("room", "near_given"):
        shadows = records[name]["depth_sensor"]["shadows"]
        assert shadows == records[name]["fill"]["stats"]["shadows"] and set(shadows) >= {"cast", "reason"}, name
    # the near capture's filled depth is the fill without a shadow prior, and differs from the fill with one
    depth, _, _ = read_depth(BUNDLED_SAMPLE / "depth.png", 8000)
    rgb = read_rgb(BUNDLED_SAMPLE / "rgb.png")
    written = np.load(sample_meshes / "near" / "depth_filled.npy")
    without = fill_depth(depth, rgb, "auto", sensor=SENSORS["none"], fx=525.0).depth
    np.testing.assert_array_equal(written, without)
    given = np.load(sample_meshes / "near_given" / "depth_filled.npy")
    assert not np.array_equal(np.nan_to_num(given), np.nan_to_num(written))


def test_preset_names_its_sensor_and_float_depth_none(inputs):
    sample = {"rgb": [str(BUNDLED_SAMPLE / "rgb.png")], "depth": [str(BUNDLED_SAMPLE / "depth.png")]}
    loaded = load_inputs(CaptureOptions(**sample, preset="kinect_v1"))
    assert loaded.first.sensor == "kinect_v1" and loaded.first.depth_scale == 1000.0
    unnamed = load_inputs(CaptureOptions(**sample, camera=str(BUNDLED_SAMPLE / "camera.json")))
    assert unnamed.first.sensor is None
    npy = load_inputs(CaptureOptions(rgb=[str(inputs / "rgb0.png")], depth=[str(inputs / "depth0.npy")],
                                     camera=str(inputs / "camera.json")))
    from rgbd2scene.reconstruct.pipeline import MeshOptions, reconstruct

    recon = reconstruct(npy.first, MeshOptions(overview=False))
    assert recon.sections["depth_sensor"]["name"] == "none" and "npy" in recon.sections["depth_sensor"]["reason"]
    assert recon.options.sensor == "none"
