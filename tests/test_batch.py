"""Batch builds (``rgbd2scene dataset CONFIG -o ROOT``): configuration errors, the deterministic plan, and real
builds of two tiny captures (160x120, rendered at 64x32, 3 frames in chunks of 2): the local pool, a local Dask
cluster of 2 workers, ``kill -9`` and resume, failures and ``--retry-failed``, ``--status`` and the gallery in a
headless browser. Ground truth is compared byte for byte between builds.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rgbd2scene.batch.config import load_config
from rgbd2scene.batch.manifest import REQUIRED_COLUMNS, gt_checksum, read_manifest, rgb_checksum
from rgbd2scene.batch.plan import make_plan, sequence_seed
from rgbd2scene.batch.run import config_diff, root_lock
from rgbd2scene.capture.camera import load_camera_json
from rgbd2scene.cli import main
from rgbd2scene.dataset import layout as ds_layout
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError
from rgbd2scene.groundtruth.geometry_cache import CACHE_DIR
from rgbd2scene.groundtruth.synthetic import write_plane_dataset
from tests.browser import Browser, chromium
from tests.conftest import BUNDLED_SAMPLE, SHARED_SAMPLES

TINY = (160, 120)
TUM = SHARED_SAMPLES / "tum_office_frame_open3d"


def _write_capture(folder: Path, rgb: np.ndarray, depth: np.ndarray, intr, depth_scale: float) -> Path:
    """A capture shrunk to TINY (area-averaged colour, nearest depth), with its camera JSON."""
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "rgb.png"), cv2.resize(rgb, TINY, interpolation=cv2.INTER_AREA))
    cv2.imwrite(str(folder / "depth.png"), cv2.resize(depth, TINY, interpolation=cv2.INTER_NEAREST))
    small = intr.resized(*TINY)
    camera = {"width": small.width, "height": small.height, "fx": small.fx, "fy": small.fy, "cx": small.cx,
              "cy": small.cy, "depth_scale": depth_scale}
    (folder / "camera.json").write_text(json.dumps(camera))
    return folder


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> Path:
    """``tissue/`` (the bundled sample) and ``second/`` (the TUM office frame when ../shared has it, else the
    bundled sample's lower-right part), each rgb.png, depth.png, camera.json at 160x120."""
    root = tmp_path_factory.mktemp("captures")
    intr, scale = load_camera_json(BUNDLED_SAMPLE / "camera.json")
    rgb = cv2.imread(str(BUNDLED_SAMPLE / "rgb.png"))
    depth = cv2.imread(str(BUNDLED_SAMPLE / "depth.png"), cv2.IMREAD_UNCHANGED)
    _write_capture(root / "tissue", rgb, depth, intr, scale)
    if TUM.is_dir():
        tum_intr, _ = load_camera_json(TUM / "camera_primesense.json")
        _write_capture(root / "second", cv2.imread(str(TUM / "TUM_color.png")),
                       cv2.imread(str(TUM / "TUM_depth.png"), cv2.IMREAD_UNCHANGED), tum_intr, 5000.0)
    else:
        from rgbd2scene.geometry.camera import Intrinsics

        crop = Intrinsics(480, 360, intr.fx, intr.fy, intr.cx - 160, intr.cy - 120)
        _write_capture(root / "second", rgb[120:, 160:], depth[120:, 160:], crop, scale)
    return root


def base_config(**changes) -> dict:
    config = {
        "seed": 7,
        "captures": [{"name": "tissue", "rgb": "tissue/rgb.png", "depth": "tissue/depth.png",
                      "camera": "tissue/camera.json", "split": "train"},
                     {"name": "second", "rgb": "second/rgb.png", "depth": "second/depth.png",
                      "camera": "second/camera.json", "split": "test", "scene": {"standoff": 0.05}}],
        "sequences": {"per_capture": 1, "frames": 3, "paths": ["scan"]},
        "render": {"size": "64x32", "samples": 1, "denoise": "none", "chunk": 2},
        "variations": {"light_power_w": [0.02, 0.08], "material": ["wet_tissue", "as_captured"]},
    }
    config.update(changes)
    return config


def write_config(folder: Path, config: dict, name: str = "batch.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def run_dataset(*args) -> int:
    return main(["dataset", *map(str, args), "--quiet"])


def npz_bytes(root: Path) -> dict[str, bytes]:
    """Every ground-truth file under ROOT (relative path -> bytes)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.glob("*/*/gt/*.npz"))}


def leftovers(root: Path) -> list[str]:
    """Scratch folders and hidden files anywhere under ROOT (none may survive a finished build); a scene's mesh
    cache (``scenes/NAME/.cache/``, :mod:`rgbd2scene.groundtruth.geometry_cache`) is kept on purpose."""
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*")
                  if (p.name.startswith(".") or p.name.endswith(".blend@"))
                  and not (p.name == CACHE_DIR or p.parent.name == CACHE_DIR))


@pytest.fixture(scope="module")
def reference(captures) -> Path:
    """The build by the default engine (local pool, one unit at a time)."""
    root = captures / "reference"
    assert run_dataset(write_config(captures, base_config()), "-o", root) == 0
    return root


# --- configuration ---------------------------------------------------------------------------------------

def _error_of(captures, capsys, config: dict | str, name: str = "bad.yaml") -> str:
    """The one error line of a configuration that must be refused before anything is written."""
    if isinstance(config, dict):
        path = write_config(captures, config, name)
    else:
        path = captures / name
        path.write_text(config)
    load_error = None
    try:
        load_config(path) and make_plan(load_config(path))
    except UserError as exc:
        load_error = str(exc)
    assert load_error is not None, f"{config} was accepted"
    never = captures / "never"
    assert run_dataset(path, "-o", never) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0] == f"error: {load_error}", err
    assert not never.exists()
    return lines[0]


def _with_capture(index: int, **changes) -> dict:
    config = base_config()
    config["captures"][index] = {**config["captures"][index], **changes}
    return config


@pytest.mark.parametrize("config, expected", [
    (base_config(colour="red"), "bad.yaml: colour: unknown key (known: seed, captures"),
    (_with_capture(0, colour="red"), "captures[0].colour: unknown key"),
    (_with_capture(1, scene={"baseline_mm": 5}), "captures[1].scene.baseline_mm: unknown key"),
    (_with_capture(1, scene={"baseline": 0.5}), "captures[1].scene.baseline: 0.5 m is not a plausible"),
    (_with_capture(1, scene={"material": "glass"}), "captures[1].scene.material: choose one of"),
    (_with_capture(0, depth="tissue/nope.png"), "captures[0].depth: "),
    (_with_capture(0, split="training"), "captures[0].split: Input should be 'train', 'val' or 'test'"),
    (_with_capture(1, split="test", name="again", rgb="tissue/rgb.png", depth="tissue/depth.png",
                   camera="tissue/camera.json"),
     "captures[1].split: again is the same capture as tissue (captures[0]) but in split 'test'"),
    (_with_capture(1, name="tissue"), "captures[1].name: 'tissue' also names a capture"),
    (base_config(render={"size": "0x128"}), "render.size: size must be positive"),
    (base_config(render={"size": "256"}), "render.size: size must look like 512x256"),
    (base_config(render={"samples": 0}), "render.samples: must be at least 1"),
    (base_config(render={"frames": 5}), "render.frames: set per sequence by sequences.frames"),
    (base_config(scene={"seed": 3}), "scene.seed: set per sequence by the sequence seed"),
    (base_config(sequences={"per_capture": 0}), "sequences.per_capture: Input should be greater than or equal to 1"),
    (base_config(sequences={"paths": ["spiral"]}), "sequences.paths[0]: choose one of"),
    (base_config(variations={"baseline": [0.004, 0.5]}), "variations.baseline: 0.5 m is not a plausible"),
    (base_config(variations={"light_power_w": [0.08, 0.02]}), "variations.light_power_w: uniform range"),
    (base_config(variations={"frames": [3, 4]}), "variations.frames: set per sequence by sequences.frames"),
    (base_config(variations={"material": {"choice": ["wet_tissue", "glass"]}}), "variations.material: choose one"),
    (base_config(variations={"baseline": 0.004}), "variations.baseline: give [lo, hi]"),
    (base_config(captures=[]), "captures: List should have at least 1 item"),
])
def test_configuration_errors_name_the_key_path(captures, capsys, config, expected):
    line = _error_of(captures, capsys, config)
    assert expected in line, line
    assert "bad.yaml" in line


def test_missing_file_and_bad_syntax_are_one_line_errors(captures, capsys):
    line = _error_of(captures, capsys, _with_capture(0, depth="tissue/nope.png"))
    assert "captures[0].depth" in line and "tissue/nope.png: file not found" in line
    line = _error_of(captures, capsys, "seed: [unclosed\n")
    assert "not valid YAML (line 2" in line or "not valid YAML (line 1" in line
    line = _error_of(captures, capsys, "seed = \n", name="bad.toml")
    assert "not valid TOML" in line
    line = _error_of(captures, capsys, "seed: 1\n", name="bad.json")
    assert "unknown configuration format" in line


@pytest.mark.parametrize("flags, expected", [
    (["--workers", "0"], "error: --workers: must be at least 1, got 0"),
    (["--jobs", "0"], "error: --jobs: must be at least 1, got 0"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "error: --workers and --scheduler: give one"),
    (["--dashboard"], "error: --dashboard: needs Dask"),
])
def test_engine_flags_are_checked_before_anything_runs(captures, capsys, flags, expected):
    assert run_dataset(write_config(captures, base_config()), "-o", captures / "never", *flags) == 2
    assert capsys.readouterr().err.startswith(expected)
    assert not (captures / "never").exists()


def test_toml_and_yaml_give_the_same_configuration(captures):
    toml = captures / "batch.toml"
    toml.write_text('''seed = 7
[[captures]]
name = "tissue"
rgb = "tissue/rgb.png"
depth = "tissue/depth.png"
camera = "tissue/camera.json"
split = "train"
[[captures]]
name = "second"
rgb = "second/rgb.png"
depth = "second/depth.png"
camera = "second/camera.json"
split = "test"
scene = { standoff = 0.05 }
[sequences]
per_capture = 1
frames = 3
paths = ["scan"]
[render]
size = "64x32"
samples = 1
denoise = "none"
chunk = 2
[variations]
light_power_w = [0.02, 0.08]
material = ["wet_tissue", "as_captured"]
''')
    from_yaml = load_config(write_config(captures, base_config(), "same.yaml"))
    from_toml = load_config(toml)
    assert from_toml.record() == from_yaml.record()
    assert [s.seed for s in make_plan(from_toml).sequences] == [s.seed for s in make_plan(from_yaml).sequences]


def test_paths_are_relative_to_the_configuration_file(captures, tmp_path):
    config = load_config(write_config(captures, base_config()))
    assert config.captures[0].rgb == str(captures / "tissue" / "rgb.png")
    # a scene option naming a file is resolved there too
    (captures / "scope.json").write_text(json.dumps({"width": 64, "height": 32, "fx": 40.0, "fy": 40.0,
                                                      "cx": 31.5, "cy": 15.5}))
    config = load_config(write_config(captures, base_config(scene={"scope_camera": "scope.json"}), "scope.yaml"))
    assert config.captures[1].scene["scope_camera"] == str(captures / "scope.json")


def test_globs_expand_into_captures_paired_by_their_wildcards(captures, tmp_path):
    for name in ("b", "a"):
        shutil.copytree(captures / "tissue", tmp_path / "scans" / name)
    (tmp_path / "scans" / "a" / "camera.json").rename(tmp_path / "camera.json")
    (tmp_path / "scans" / "b" / "camera.json").unlink()
    entry = {"name": "scan", "rgb": "scans/*/rgb.png", "depth": "scans/*/depth.png", "camera": "camera.json"}
    config = load_config(write_config(tmp_path, base_config(captures=[entry])))
    assert [c.name for c in config.captures] == ["scan_a", "scan_b"]
    assert [Path(c.depth).parent.name for c in config.captures] == ["a", "b"]
    assert all(c.camera == str(tmp_path / "camera.json") for c in config.captures)
    (tmp_path / "scans" / "b" / "depth.png").rename(tmp_path / "scans" / "b" / "depth_old.png")
    with pytest.raises(Exception, match=r"captures\[0\]\.depth: nothing matches .*scans/b/rgb.png"):
        load_config(write_config(tmp_path, base_config(captures=[entry])))


def test_plan_is_deterministic_and_independent_of_order(captures):
    config = base_config(sequences={"per_capture": 3, "frames": 3, "paths": ["scan", "orbit"]})
    plan = make_plan(load_config(write_config(captures, config, "plan.yaml")))
    again = make_plan(load_config(write_config(captures, config, "plan.yaml")))
    assert [(s.name, s.seed, s.path, s.sampled) for s in plan.sequences] == \
           [(s.name, s.seed, s.path, s.sampled) for s in again.sequences]
    assert [s.name for s in plan.sequences] == ["tissue_000", "tissue_001", "tissue_002",
                                                "second_000", "second_001", "second_002"]
    assert [s.path for s in plan.sequences[:3]] == ["scan", "orbit", "scan"]
    assert len({s.seed for s in plan.sequences}) == 6
    assert all(s.seed == sequence_seed(7, s.name) == s.scene.seed for s in plan.sequences)
    assert all(0.02 <= s.scene.light_power_w <= 0.08 and s.scene.light_power_w == s.sampled["light_power_w"]
               for s in plan.sequences)
    assert {s.scene.standoff for s in plan.sequences if s.capture.name == "second"} == {0.05}
    # reversing the captures, or adding a variation, leaves every sequence's seed and draws as they were
    config["captures"] = config["captures"][::-1]
    config["variations"] = {**config["variations"], "baseline": [0.004, 0.006]}
    other = {s.name: s for s in make_plan(load_config(write_config(captures, config, "plan.yaml"))).sequences}
    for s in plan.sequences:
        o = other[s.name]
        assert (o.seed, o.sampled["light_power_w"], o.sampled["material"]) == \
               (s.seed, s.sampled["light_power_w"], s.sampled["material"])
        assert 0.004 <= o.scene.baseline <= 0.006


def test_config_diff_names_the_keys_that_differ(captures):
    old = load_config(write_config(captures, base_config())).record()
    config = _with_capture(1, split="val")
    config["render"] = {**config["render"], "samples": 4, "chunk": 10}
    new = load_config(write_config(captures, config, "changed.yaml")).record()
    assert config_diff(old, new) == ["captures[1].split", "render.samples"]  # render.chunk may change


def test_rgb_checksum_covers_every_png_and_only_the_pngs(tmp_path):
    """Two writes of the same dataset give one checksum; a changed byte of any rgb or rgb_clean PNG changes it,
    a changed npz does not (that is the ground truth's checksum), and hashlib over the same stream agrees."""
    import hashlib

    a, b = write_plane_dataset(tmp_path / "a", frames=2), write_plane_dataset(tmp_path / "b", frames=2)
    assert rgb_checksum(a, 2) == rgb_checksum(b, 2) != "" and gt_checksum(a, 2) == gt_checksum(b, 2)
    expected = hashlib.sha256()
    for index in range(2):
        for eye in ("left", "right"):
            name = f"{eye}/rgb/{index:06d}.png"
            expected.update(f"{name}\n".encode() + (a / name).read_bytes())
    assert rgb_checksum(a, 2) == expected.hexdigest()
    assert rgb_checksum(a, 1) != rgb_checksum(a, 2)
    clean = ds_layout.clean_rgb_path(b, "right", 1)
    clean.parent.mkdir()
    clean.write_bytes(ds_layout.frame_paths(b, "right", 1).rgb.read_bytes())
    assert rgb_checksum(b, 2) != rgb_checksum(a, 2)
    for path in (ds_layout.frame_paths(a, "left", 1).rgb, clean):
        before = rgb_checksum(path.parents[2], 2)
        data = bytearray(path.read_bytes())
        data[-20] ^= 1
        path.write_bytes(bytes(data))
        assert rgb_checksum(path.parents[2], 2) != before
    gt = ds_layout.frame_paths(a, "left", 0).gt
    before_rgb, before_gt = rgb_checksum(a, 2), gt_checksum(a, 2)
    gt.write_bytes(gt.read_bytes() + b"\0")
    assert rgb_checksum(a, 2) == before_rgb and gt_checksum(a, 2) != before_gt
    assert rgb_checksum(tmp_path / "missing", 2) == ""


# --- builds ----------------------------------------------------------------------------------------------

def test_reference_build_manifest_datasets_and_status(reference, capsys):
    import pandas as pd

    table = pd.read_csv(reference / "manifest.csv", keep_default_na=False)
    assert tuple(table.columns[:len(REQUIRED_COLUMNS)]) == REQUIRED_COLUMNS
    assert list(table["sequence"]) == ["tissue_000", "second_000"]
    assert list(table["split"]) == ["train", "test"] and set(table["status"]) == {"done"}
    assert list(table["seed"]) == [sequence_seed(7, "tissue_000"), sequence_seed(7, "second_000")]
    assert {"light_power_w", "material", "gt_sha256", "frames_done"} <= set(table.columns)
    assert table["light_power_w"].between(0.02, 0.08).all()
    for row in table.itertuples():
        ds = Dataset(reference / row.sequence)
        assert (ds.width, ds.height, ds.frames) == (64, 32, 3)
        assert ds.frame_indices() == [0, 1, 2]
        assert row.gt_sha256 == gt_checksum(reference / row.sequence, 3) != ""
        assert row.rgb_sha256 == rgb_checksum(reference / row.sequence, 3) != ""
        assert row.frames_done == 3
        assert (reference / row.sequence / "contact_sheet.png").is_file()
        scene = json.loads((reference / "scenes" / row.sequence / "scene.json").read_text())
        assert scene["scene_options"]["seed"] == row.seed
        assert scene["scene_options"]["light_power_w"] == row.light_power_w
        assert ds.meta["seed"] == row.seed  # the Cycles seed of its RGB noise
        mesh = reference / "meshes" / row.capture / "mesh.ply"  # the scene shares the capture's mesh files
        assert (reference / "scenes" / row.sequence / "mesh.ply").stat().st_ino == mesh.stat().st_ino
    assert json.loads((reference / "config.json").read_text())["seed"] == 7
    assert leftovers(reference) == []
    # evaluate reads the ROOT as a batch, one table per split
    from rgbd2scene.evaluate.run import find_sequences

    sequences, batch = find_sequences(reference)
    assert batch and [(s.split, s.name) for s in sequences] == [("train", "tissue_000"), ("test", "second_000")]
    assert main(["dataset", "--status", str(reference)]) == 0
    out = capsys.readouterr().out
    assert "2 sequences from 2 captures; no build running" in out
    assert "done           1      1      2" in out and "frames: 6 of 6 done (100 %)" in out


def test_rerun_does_nothing_and_changed_configuration_is_refused(reference, captures, capsys):
    before = {p: p.stat().st_ino for p in reference.rglob("*.npz")}
    assert run_dataset(write_config(captures, base_config()), "-o", reference) == 0
    assert {p: p.stat().st_ino for p in reference.rglob("*.npz")} == before  # no file written again
    config = base_config(render={"size": "64x32", "samples": 2, "denoise": "none", "chunk": 1})
    assert run_dataset(write_config(captures, config, "changed.yaml"), "-o", reference) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "(render.samples differ)" in err and len(err.splitlines()) == 1
    with root_lock(reference):
        assert run_dataset(write_config(captures, base_config()), "-o", reference) == 2
    assert "another 'rgbd2scene dataset' build is running" in capsys.readouterr().err


def test_local_dask_cluster_gives_byte_identical_ground_truth(reference, captures):
    root = captures / "dask"
    assert run_dataset(write_config(captures, base_config()), "-o", root, "--workers", "2") == 0
    expected = npz_bytes(reference)
    assert len(expected) == 2 * 2 * 3
    assert npz_bytes(root) == expected
    # the same configuration gives the same bytes, images included
    assert [(r.sequence, r.seed, r.settings, r.gt_sha256, r.rgb_sha256) for r in read_manifest(root)] == \
           [(r.sequence, r.seed, r.settings, r.gt_sha256, r.rgb_sha256) for r in read_manifest(reference)]
    assert leftovers(root) == []


def group_stopped(pgid: int) -> bool:
    """Whether every thread of process group ``pgid`` is stopped (or dead), from ``/proc/*/task/*/stat``.

    A thread that was starting a process (``subprocess`` uses ``vfork``) waits in the kernel, uninterruptibly,
    for its child to exec; the child is in the group and stopped, so the thread can do nothing either: it counts
    as stopped.
    """
    for task in Path("/proc").glob("[0-9]*/task/*"):
        try:
            text = (task / "stat").read_text()
            state, _ppid, group = text[text.rindex(")") + 2:].split()[:3]
            if int(group) != pgid or state in "TtZX":
                continue
            if state == "D" and (task / "wchan").read_text() == "kernel_clone":
                continue
        except OSError:  # the thread ended while listed
            continue
        return False
    return True


def test_kill_9_then_resume_equals_an_uninterrupted_build(reference, captures):
    """Kill the whole build (driver and Blender workers) mid-chunk, once a frame's npz has landed while
    another frame has only its images; the same command finishes it, keeps what was finished, sweeps the
    dead run's files, and the ground truth is byte-identical to the reference (the resumed chunk writes a
    half-done frame's missing half only)."""
    root = captures / "killed"
    config = write_config(captures, base_config())
    proc = subprocess.Popen([sys.executable, "-m", "rgbd2scene.cli", "dataset", str(config), "-o", str(root),
                             "--quiet"], start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def half_done() -> list[Path]:
        """Frames with their images but not their ground truth, or (the ground truth comes from the scene
        model while Blender renders the images) the other way round."""
        png = {p.parent.parent.parent / p.stem for p in root.glob("*/left/rgb/*.png")}
        npz = {p.parent.parent.parent / p.stem for p in root.glob("*/left/gt/*.npz")}
        return sorted(png ^ npz)

    def stopped_mid_chunk() -> bool:
        """Freeze the build and look: the files it is killed on are the files checked (polling a running
        build, the chunk's last npz could land between the look and the kill). SIGSTOP is asynchronous: a
        write or rename in flight completes after ``killpg`` returns, so look only once every thread of the
        group is stopped (a png landing between the two globs once made a finished frame look half done)."""
        os.killpg(proc.pid, signal.SIGSTOP)
        deadline = time.monotonic() + 10
        while not group_stopped(proc.pid):
            assert time.monotonic() < deadline, "the build's processes did not stop"
            time.sleep(0.001)
        if list(root.glob("*/left/gt/*.npz")) and half_done():
            return True
        os.killpg(proc.pid, signal.SIGCONT)
        return False

    deadline = time.monotonic() + 600
    try:
        while not stopped_mid_chunk():
            assert proc.poll() is None, "the build ended before it was killed"
            assert time.monotonic() < deadline
            time.sleep(0.02)
    finally:  # killed mid-chunk, or the test failed: nothing is left running (or stopped) behind it
        with contextlib.suppress(ProcessLookupError):  # the build had ended: the assertion above says so
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    time.sleep(0.5)  # the killed Blender workers' files
    assert list(root.glob("*/.work/*")), "the killed worker left no scratch folder to sweep"
    assert half_done(), "no frame had its images but not its ground truth (or the reverse) when killed"
    # a frame is finished when both eyes' images are there (killed between the two, it is rendered again)
    stereo = {(p.parents[2], p.name) for p in root.glob("*/left/rgb/*.png")} & \
             {(p.parents[2], p.name) for p in root.glob("*/right/rgb/*.png")}
    kept = {p: p.stat().st_ino for p in root.glob("*/*/rgb/*.png") if (p.parents[2], p.name) in stereo}
    assert kept
    assert run_dataset(config, "-o", root) == 0
    assert npz_bytes(root) == npz_bytes(reference)
    assert {p: p.stat().st_ino for p in kept} == kept  # finished images were not rendered again
    assert leftovers(root) == []
    assert [(r.gt_sha256, r.rgb_sha256) for r in read_manifest(root)] == \
           [(r.gt_sha256, r.rgb_sha256) for r in read_manifest(reference)]


def test_failed_sequence_is_recorded_and_retried_alone(reference, captures, tmp_path, capsys):
    """A corrupt depth file fails its capture's sequences (manifest, log, status, exit 1) and not the others (one
    of them built from an existing scene folder); once fixed, only ``--retry-failed`` redoes them."""
    shutil.copytree(captures / "tissue", tmp_path / "tissue")
    shutil.copytree(captures / "tissue", tmp_path / "broken")
    (tmp_path / "broken" / "depth.png").write_bytes(b"not a png at all")
    config = base_config(sequences={"per_capture": 1, "frames": 2, "paths": ["scan"]}, variations={})
    config["captures"] = [config["captures"][0],
                          {"name": "broken", "rgb": "broken/rgb.png", "depth": "broken/depth.png",
                           "camera": "broken/camera.json", "split": "val"},
                          {"name": "reused", "scene": {"folder": str(reference / "scenes" / "tissue_000"),
                                                       "baseline": 0.004}}]
    path = write_config(tmp_path, config)
    root = tmp_path / "root"
    assert run_dataset(path, "-o", root) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: 1 sequence(s) failed, first broken_000: mesh: ")
    rows = {r.sequence: r for r in read_manifest(root)}
    assert rows["tissue_000"].status == "done" and rows["broken_000"].status == "failed"
    assert rows["reused_000"].status == "done" and Dataset(root / "reused_000").baseline == 0.004
    assert rows["broken_000"].error.startswith("mesh: ") and "broken/depth.png" in rows["broken_000"].error
    assert "broken/depth.png" in (root / "logs" / "broken_000.log").read_text()
    assert main(["dataset", "--status", str(root)]) == 0
    status = capsys.readouterr().out
    assert "failed         0      1      1" in status  # train, val, total
    assert "done           2      0      2" in status
    assert f"broken_000 (val): {rows['broken_000'].error}" in status
    good = {p: p.stat().st_ino for p in root.glob("[tr]*_000/**/*") if p.is_file()}

    shutil.copy(captures / "tissue" / "depth.png", tmp_path / "broken" / "depth.png")  # the capture is fixed
    assert run_dataset(path, "-o", root) == 1  # a plain rerun leaves failed sequences alone
    assert {r.sequence: r.status for r in read_manifest(root)} == {"tissue_000": "done", "broken_000": "failed",
                                                                   "reused_000": "done"}
    assert run_dataset(path, "-o", root, "--retry-failed") == 0
    rows = {r.sequence: r for r in read_manifest(root)}
    assert rows["broken_000"].status == "done" and rows["broken_000"].error == ""
    assert {p: p.stat().st_ino for p in good} == good  # the done sequence was not touched
    assert leftovers(root) == []


@pytest.mark.skipif(chromium() is None, reason="chromium is not installed (make test installs Debian's)")
def test_gallery_renders_in_a_headless_browser_with_every_image(reference, tmp_path):
    index = reference / "index.html"
    with Browser(chromium()) as browser:
        browser.open(index)
        assert browser.evaluate("document.title").startswith("rgbd2scene batch")
        images = browser.images()
        assert len(images) == 2 * 7  # two sequences: both eyes and five maps each
        assert [i["src"] for i in images if not i["loaded"]] == []
        assert browser.evaluate("document.querySelectorAll('div.sequence').length") == 2
        links = browser.evaluate("Array.from(document.links).map(a => a.getAttribute('href'))")
        assert all((reference / link).exists() for link in links), links
        shot = cv2.imdecode(np.frombuffer(browser.screenshot(), np.uint8), cv2.IMREAD_COLOR)
        assert shot is not None and shot.std() > 10  # not a blank page

        # the check fails when an image does not resolve
        copy = tmp_path / "copy"
        shutil.copytree(reference / "gallery", copy / "gallery")
        shutil.copy(index, copy / "index.html")
        (copy / "gallery" / "second_000" / "depth.png").unlink()
        browser.open(copy / "index.html")
        assert [i["src"] for i in browser.images() if not i["loaded"]] == ["gallery/second_000/depth.png"]


def test_dask_dashboard_is_served_when_asked(captures):
    import urllib.request

    from rgbd2scene.batch.engine import open_engine

    engine = open_engine(workers=1, dashboard=True)
    try:
        assert engine.info.dashboard and engine.info.dashboard in engine.info.describe()
        with urllib.request.urlopen(engine.info.dashboard, timeout=30) as page:
            assert page.status == 200 and b"Dask" in page.read()
    finally:
        engine.close()


def test_a_failed_chunk_fails_its_sequence_only(captures, tmp_path, monkeypatch):
    """The driver with stub units (no Blender): the first chunk of one sequence fails; its other chunk's result
    is ignored, the other sequence finishes, the error and the log name the failure."""
    from types import SimpleNamespace

    from rgbd2scene.batch import run
    from rgbd2scene.batch.engine import LocalEngine
    from rgbd2scene.batch.tasks import Outcome

    plan = make_plan(load_config(write_config(captures, base_config(), "stub.yaml")))
    calls = []

    def fake_job(scene_dir, out, options):
        return SimpleNamespace(out=Path(out), frames=3, with_gt=True, chunks=lambda: [[0, 1], [2]],
                               incomplete=lambda frames: [])

    def fake_chunk(job, group):
        calls.append((job.out.name, group))
        if job.out.name == "second_000" and group == [0, 1]:
            return Outcome(False, 0.5, "render worker failed (exit status 1) on frames 0-1", "the whole log")
        return Outcome(True, 0.5, peak_rss_mb=100.0)

    monkeypatch.setattr(run, "build_mesh", lambda capture, out: Outcome(True, 0.1))
    monkeypatch.setattr(run, "build_scene", lambda source, out, options: Outcome(True, 0.1))
    monkeypatch.setattr(run, "_complete", lambda folder: False)
    monkeypatch.setattr(run, "prepare_render", fake_job)
    monkeypatch.setattr(run, "render_chunk", fake_chunk)
    monkeypatch.setattr("rgbd2scene.pictures.contact_sheet.write_frame_sheet", lambda *args: None)
    rows = run.merge_rows(plan, [], tmp_path, retry_failed=False)
    engine = LocalEngine(1)
    driver = run._Driver(plan, tmp_path, engine, rows, progress=False)
    try:
        driver.run(plan.sequences)
    finally:
        engine.close()
    assert rows["tissue_000"].status == "done" and rows["tissue_000"].error == ""
    assert rows["second_000"].status == "failed"
    assert rows["second_000"].error == "render: render worker failed (exit status 1) on frames 0-1"
    assert "the whole log" in (tmp_path / "logs" / "second_000.log").read_text()
    assert driver.unit_seconds > 0 and driver.peaks == [100.0, 100.0]  # the failed sequence's chunks not counted
    assert {r.sequence: r.status for r in read_manifest(tmp_path)} == {"tissue_000": "done", "second_000": "failed"}
