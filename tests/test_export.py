"""``rgbd2scene export``: KITTI, SceneFlow and VisionBlender layouts read back with OpenCV's own readers (and a
hand parser of the PFM header) and compared with the dataset's npz files."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from rgbd2scene.cli import main
from rgbd2scene.dataset import Dataset
from rgbd2scene.dataset.layout import frame_paths, write_gt
from rgbd2scene.export import FORMATS
from rgbd2scene.export.kitti import encode_disparity, encode_flow
from rgbd2scene.groundtruth.synthetic import PlaneScene, write_plane_dataset

cv2 = pytest.importorskip("cv2")
FRAMES = 3


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    # step 2 mm per frame: flow of ~-1.7 px, so some pixels leave the image (occluded_forward)
    root = write_plane_dataset(tmp_path_factory.mktemp("plane") / "ds", FRAMES, PlaneScene(step=0.002))
    return Dataset(root)


@pytest.fixture(scope="module")
def exported(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("export")
    for name in FORMATS:
        assert main(["export", str(dataset.root), "--format", name, "-o", str(out / name), "--quiet"]) == 0
    return out


def test_kitti_disparity_png(dataset, exported):
    for i in range(FRAMES):
        png = cv2.imread(str(exported / "kitti" / "disp_occ_0" / f"{i:06d}_10.png"), cv2.IMREAD_UNCHANGED)
        d = dataset.gt("left", i, ("disparity",))["disparity"]
        assert png.dtype == np.uint16 and png.shape == d.shape
        valid = png > 0
        np.testing.assert_array_equal(valid, np.isfinite(d))
        assert valid.sum() > 100 and (~valid).sum() > 100  # plane and background
        np.testing.assert_allclose(png[valid] / 256.0, d[valid], atol=0.5 / 256 + 1e-6)


def test_kitti_flow_png_channel_order(dataset, exported):
    """The devkit's PNG order is R, G, B = u, v, valid: OpenCV returns B, G, R = valid, v, u."""
    for i in range(FRAMES - 1):
        gt = dataset.gt("left", i, ("flow_forward", "occluded_forward"))
        flow = gt["flow_forward"]
        for folder, expect_valid in (("flow_occ", np.isfinite(flow).all(-1)),
                                     ("flow_noc", np.isfinite(flow).all(-1) & ~gt["occluded_forward"])):
            bgr = cv2.imread(str(exported / "kitti" / folder / f"{i:06d}_10.png"), cv2.IMREAD_UNCHANGED)
            assert bgr.dtype == np.uint16 and bgr.shape == (*flow.shape[:2], 3)
            valid = bgr[..., 0] == 1
            np.testing.assert_array_equal(valid, expect_valid)
            u = (bgr[..., 2].astype(float) - 2**15) / 64.0
            v = (bgr[..., 1].astype(float) - 2**15) / 64.0
            np.testing.assert_allclose(u[valid], flow[valid][:, 0], atol=0.5 / 64 + 1e-6)
            np.testing.assert_allclose(v[valid], flow[valid][:, 1], atol=0.5 / 64 + 1e-6)
        assert gt["occluded_forward"].any() and not gt["occluded_forward"].all()
    assert not (exported / "kitti" / "flow_occ" / f"{FRAMES - 1:06d}_10.png").exists()  # last frame: no flow


def test_kitti_images_pairs_and_calib(dataset, exported):
    kitti = exported / "kitti"
    for i in range(FRAMES):
        assert (kitti / "image_2" / f"{i:06d}_10.png").read_bytes() == dataset.rgb_file("left", i).read_bytes()
        assert (kitti / "image_3" / f"{i:06d}_10.png").read_bytes() == dataset.rgb_file("right", i).read_bytes()
    # the second image of pair i is frame i+1
    assert (kitti / "image_2" / "000000_11.png").read_bytes() == dataset.rgb_file("left", 1).read_bytes()
    assert not (kitti / "image_2" / f"{FRAMES - 1:06d}_11.png").exists()
    calib = dict(line.split(":", 1) for line in (kitti / "calib_cam_to_cam" / "000000.txt").read_text().splitlines())
    P3 = np.array(calib["P_rect_03"].split(), float).reshape(3, 4)
    np.testing.assert_allclose(P3[:, :3], dataset.K)
    assert P3[0, 3] == pytest.approx(-dataset.fx * dataset.baseline)


def test_kitti_encoders_mark_unstorable_values_invalid():
    d = encode_disparity(np.array([[np.nan, 300.0, 1.5, -2.0]], np.float32))
    np.testing.assert_array_equal(d, [[0, 0, 384, 0]])
    f = encode_flow(np.array([[[600.0, 0.0], [1.0, -2.0], [np.nan, 0.0]]], np.float32))
    np.testing.assert_array_equal(f[0, :, 2], [0, 1, 0])
    np.testing.assert_array_equal(f[0, 1, :2], [2**15 + 64, 2**15 - 128])


def _parse_pfm(path):
    """Independent PFM reader: header lines, then float32 rows bottom to top (little-endian for a negative scale)."""
    data = path.read_bytes()
    tag, size, scale, rest = data.split(b"\n", 3)
    w, h = (int(x) for x in size.split())
    assert tag == b"Pf" and float(scale) < 0
    return np.frombuffer(rest, "<f4").reshape(h, w)[::-1]


def test_sceneflow_pfm_disparity_and_flo_flow(dataset, exported):
    sf = exported / "sceneflow"
    for i in range(FRAMES):
        for eye in ("left", "right"):
            gt = dataset.gt(eye, i, ("disparity", "flow_forward", "flow_backward"))
            path = sf / "disparity" / eye / f"{i:06d}.pfm"
            via_cv = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(via_cv, gt["disparity"])  # NaN where no surface, equal_nan
            np.testing.assert_array_equal(_parse_pfm(path), gt["disparity"])
            for key, folder, exists in (("flow_forward", "into_future", i < FRAMES - 1),
                                        ("flow_backward", "into_past", i > 0)):
                flo = sf / "optical_flow" / folder / eye / f"{i:06d}.flo"
                assert flo.exists() == exists
                if exists:
                    flow = cv2.readOpticalFlow(str(flo))
                    known = np.isfinite(gt[key]).all(-1)
                    np.testing.assert_array_equal(flow[known], gt[key][known])
                    assert (flow[~known] > 1e9).all() and (~known).any()
            assert (sf / "frames_cleanpass" / eye / f"{i:06d}.png").read_bytes() == \
                dataset.rgb_file(eye, i).read_bytes()


def test_visionblender_npz(dataset, exported):
    vb = exported / "visionblender"
    for i in range(FRAMES):
        for eye, suffix in (("left", "_L"), ("right", "_R")):
            gt = dataset.gt(eye, i)
            with np.load(vb / f"{i:04d}{suffix}.npz") as z:  # no pickle needed: plain and structured arrays
                surface = np.isfinite(gt["depth"])
                np.testing.assert_allclose(z["depth_map"][surface], gt["depth"][surface])
                assert (z["depth_map"][~surface] == -1).all()
                assert (z["disparity_map"][~surface] == 0).all()
                np.testing.assert_allclose(z["disparity_map"][surface], gt["disparity"][surface])
                np.testing.assert_allclose(z["extrinsic_mat"] @ np.append(gt["T_world_cam"][:3, 3], 1), 0,
                                           atol=1e-12)  # world -> camera maps the camera centre to 0
                np.testing.assert_allclose(z["intrinsic_mat"], gt["K"])
                # world-frame normals (the dataset's camera frame rotated by T_world_cam)
                n_world = z["normal_map"][surface]
                np.testing.assert_allclose(n_world @ gt["T_world_cam"][:3, :3], gt["normals"][surface], atol=1e-6)
                flow_ok = np.isfinite(gt["flow_forward"]).all(-1)
                np.testing.assert_allclose(z["optical_flow"][flow_ok], gt["flow_forward"][flow_ok], atol=1e-6)
                assert (z["optical_flow"][~flow_ok] == 0).all()
                np.testing.assert_array_equal(z["segmentation_masks"], gt["segmentation"])
                assert list(z["segmentation_masks_indexes"]["name"]) == ["plane"]
                assert z["object_poses"]["name"][0] == "plane"
                np.testing.assert_allclose(z["object_poses"]["pose"][0], gt["object_poses"][0])
            assert (vb / f"{i:04d}{suffix}.png").read_bytes() == dataset.rgb_file(eye, i).read_bytes()


def test_export_leaves_no_temporary_files(exported):
    assert not [p for p in exported.rglob(".*")]


def test_export_bad_inputs_exit_2(dataset, tmp_path, capsys):
    assert main(["export", str(tmp_path / "missing"), "--format", "kitti", "-o", str(tmp_path / "o")]) == 2
    assert "dataset.json" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["export", str(dataset.root), "--format", "middlebury", "-o", str(tmp_path / "o")])
    assert exc.value.code == 2
    capsys.readouterr()
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["export", str(dataset.root), "--format", "kitti", "-o", str(blocker), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and str(blocker) in err and err.count("\n") == 1


@pytest.mark.parametrize("name", ["kitti", "sceneflow", "visionblender"])
def test_a_dataset_without_disparity_is_refused_before_anything_is_written(dataset, tmp_path, capsys, name):
    # a raw (distorted) pair, or a render whose --gt left disparity out: the first frame's left file lacks it
    root = tmp_path / "ds"
    shutil.copytree(dataset.root, root)
    first = frame_paths(root, "left", 0).gt
    with np.load(first) as z:
        kept = {k: z[k] for k in z.files if k != "disparity"}
    write_gt(first, kept)
    out = tmp_path / name
    assert main(["export", str(root), "--format", name, "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "000000.npz" in err and "disparity" in err
    assert not out.exists() or not any(p.is_file() for p in out.rglob("*"))
