"""``rgbd2scene evaluate``: sanity of the metrics (ground truth scores zero, a 1-px offset scores what the
formula predicts), invalid predictions never dropped silently, prediction folders, batch roots, bad inputs."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from rgbd2scene.cli import main
from rgbd2scene.dataset import Dataset
from rgbd2scene.evaluate.metrics import METRICS, depth_metrics, fill_invalid, score_frame
from rgbd2scene.files.flowio import write_pfm
from rgbd2scene.groundtruth.synthetic import PlaneScene, write_plane_dataset

FRAMES = 3


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return Dataset(write_plane_dataset(tmp_path_factory.mktemp("plane") / "ds", FRAMES))


def _expected(pred_depth: np.ndarray, gt_depth: np.ndarray) -> dict:
    """The metrics written out again from their definitions (depths in metres, RMSE and Sq Rel in mm)."""
    z, t = pred_depth.astype(np.float64), gt_depth.astype(np.float64)
    r = np.maximum(z / t, t / z)
    return {"rmse_mm": 1000 * np.sqrt(np.mean((z - t) ** 2)), "abs_rel": np.mean(np.abs(z - t) / t),
            "sq_rel": np.mean((1000 * (z - t)) ** 2 / (1000 * t)), "rmse_log": np.sqrt(np.mean(np.log(z / t) ** 2)),
            "a1": np.mean(r < 1.25), "a2": np.mean(r < 1.5625), "a3": np.mean(r < 1.953125)}


def _read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_ground_truth_disparity_scores_zero(dataset):
    gt = dataset.gt("left", 1)
    score = score_frame(gt["disparity"], gt["depth"], dataset.fx, dataset.baseline, fallback_disparity=1.0)
    assert score.density == 1.0 and score.gt_pixels == np.isfinite(gt["depth"]).sum()
    for scoring in ("all", "valid"):
        m = score.metrics[scoring]
        assert m["rmse_mm"] < 1e-4 and m["abs_rel"] < 1e-6 and m["rmse_log"] < 1e-6
        assert m["a1"] == m["a2"] == m["a3"] == 1.0


def test_one_pixel_offset_scores_the_formula(dataset):
    gt = dataset.gt("left", 0)
    d, z = gt["disparity"].astype(np.float64), gt["depth"]
    ok = np.isfinite(z)
    score = score_frame(d + 1.0, z, dataset.fx, dataset.baseline, fallback_disparity=1.0)
    expected = _expected(dataset.fx * dataset.baseline / (d[ok] + 1.0), z[ok])
    for name in METRICS:
        assert score.metrics["all"][name] == pytest.approx(expected[name], rel=1e-5), name
        assert score.metrics["valid"][name] == pytest.approx(expected[name], rel=1e-5), name
    # and it is not a small error: one pixel at d ~ 4 px is about 20 % of the depth
    assert 0.15 < score.metrics["all"]["abs_rel"] < 0.25


def test_invalid_predictions_are_counted_and_filled(dataset):
    gt = dataset.gt("left", 0)
    z = gt["depth"]
    ok = np.isfinite(z)
    pred = gt["disparity"] + 1.0
    pred[:, : dataset.width // 2] = np.nan  # the method gives nothing on the left half
    pred[0, -1] = -3.0  # a negative value is no prediction either
    score = score_frame(pred, z, dataset.fx, dataset.baseline, fallback_disparity=1.0)
    valid = ok & np.isfinite(pred) & (pred > 0)
    assert score.density == pytest.approx(valid.sum() / ok.sum())
    assert score.density < 0.6
    fB = dataset.fx * dataset.baseline
    assert score.metrics["valid"]["rmse_mm"] == pytest.approx(
        _expected(fB / pred[valid], z[valid])["rmse_mm"], rel=1e-5)
    # "all": each invalid pixel takes its nearest valid neighbour's disparity, every GT pixel is scored
    filled = fill_invalid(pred, 1.0)
    assert np.isfinite(filled).all()
    assert filled[5, 0] == pred[5, dataset.width // 2]  # the nearest valid pixel along the row
    assert score.metrics["all"]["rmse_mm"] == pytest.approx(_expected(fB / filled[ok], z[ok])["rmse_mm"], rel=1e-5)
    nothing = score_frame(np.full_like(pred, np.nan), z, dataset.fx, dataset.baseline, fallback_disparity=2.0)
    assert nothing.density == 0.0 and np.isnan(nothing.metrics["valid"]["rmse_mm"])
    assert nothing.metrics["all"]["rmse_mm"] == pytest.approx(_expected(np.full(ok.sum(), fB / 2.0), z[ok])["rmse_mm"],
                                                              rel=1e-5)


def test_depth_metrics_reject_mismatched_input():
    with pytest.raises(ValueError, match="size"):
        depth_metrics(np.ones(3), np.ones(4))
    assert np.isnan(depth_metrics(np.zeros(0), np.zeros(0))["rmse_mm"])


def test_predictions_folder_npy_and_pfm_via_cli(dataset, tmp_path):
    preds = tmp_path / "net"
    preds.mkdir()
    for i in range(FRAMES):
        d = dataset.gt("left", i, ("disparity",))["disparity"] + np.float32(1.0)
        if i % 2:
            write_pfm(preds / f"{i:06d}.pfm", d)
        else:
            np.save(preds / f"{i:06d}.npy", d)
    out = tmp_path / "eval"
    assert main(["evaluate", str(dataset.root), "--methods", "gt", "--predictions", f"mynet={preds}", "-o", str(out),
                 "--quiet"]) == 0
    rows = {(r["method"], r["scored"]): r for r in _read_csv(out / "metrics.csv")}
    assert list(_read_csv(out / "metrics.csv")[0])[:4] == ["method", "frames", "rmse_mm", "rmse_mm_std"]
    assert float(rows["gt", "all"]["rmse_mm"]) < 1e-4 and float(rows["gt", "all"]["density"]) == 1.0
    per_frame = []
    for i in range(FRAMES):
        gt = dataset.gt("left", i, ("disparity", "depth"))
        ok = np.isfinite(gt["depth"])
        per_frame.append(_expected(dataset.fx * dataset.baseline / (gt["disparity"][ok] + np.float32(1.0)),
                                   gt["depth"][ok]))
    for name in METRICS:
        values = [p[name] for p in per_frame]
        assert float(rows["mynet", "all"][name]) == pytest.approx(np.mean(values), rel=1e-4), name
        assert float(rows["mynet", "all"][f"{name}_std"]) == pytest.approx(np.std(values), rel=1e-3, abs=1e-9)
    assert rows["mynet", "all"]["frames"] == str(FRAMES)
    frames = _read_csv(out / "per_frame.csv")
    assert len(frames) == 2 * 2 * FRAMES  # methods x scorings x frames
    assert (out / "metrics.md").read_text().count("| mynet |") == 2
    maps = sorted(p.name for p in (out / "error_maps").iterdir())
    assert len(maps) == 4 and any(n.startswith("mynet_worst_") for n in maps)


def test_builtin_methods_on_textured_plane(tmp_path):
    """SGBM and ELAS find the plane: most ground-truth pixels matched, depth within a few percent."""
    pytest.importorskip("elas")
    root = write_plane_dataset(tmp_path / "ds", 2, PlaneScene(width=160, height=80, fx=100.0))
    assert main(["evaluate", str(root), "--quiet", "--no-error-maps"]) == 0
    rows = {(r["method"], r["scored"]): r for r in _read_csv(root / "evaluation" / "metrics.csv")}
    for method in ("sgbm", "elas"):
        assert float(rows[method, "valid"]["density"]) > 0.5, method
        assert float(rows[method, "valid"]["abs_rel"]) < 0.05, method
        assert float(rows[method, "all"]["a1"]) > 0.95, method
    assert not (root / "evaluation" / "error_maps").exists()


def _manifest(root, rows):
    cols = ["sequence", "capture", "split", "seed", "path", "frames", "status", "error"]
    with open(root / "manifest.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, cols)
        writer.writeheader()
        for r in rows:
            writer.writerow({c: r.get(c, "") for c in cols})


def test_batch_root_one_table_per_split(tmp_path):
    root = tmp_path / "root"
    write_plane_dataset(root / "seq_a", 2)
    write_plane_dataset(root / "seq_b", 3, PlaneScene(z0=0.06))
    write_plane_dataset(root / "seq_c", 2)
    _manifest(root, [{"sequence": "seq_a", "split": "train", "status": "done", "frames": 2},
                     {"sequence": "seq_b", "split": "test", "status": "done", "frames": 3},
                     {"sequence": "seq_c", "split": "test", "status": "failed", "error": "boom"},
                     {"sequence": "seq_d", "split": "val", "status": "pending"}])
    assert main(["evaluate", str(root), "--methods", "gt,sgbm", "--quiet"]) == 0
    out = root / "evaluation"
    rows = _read_csv(out / "metrics.csv")
    assert {(r["split"], r["method"], r["scored"]) for r in rows} == {
        (s, m, sc) for s in ("train", "test") for m in ("gt", "sgbm") for sc in ("all", "valid")}
    frames = {r["split"]: r["frames"] for r in rows if r["method"] == "gt"}
    assert frames == {"train": "2", "test": "3"}  # the failed and pending sequences are left out
    sequences = {r["sequence"] for r in _read_csv(out / "per_frame.csv")}
    assert sequences == {"seq_a", "seq_b"}
    report = (out / "metrics.md").read_text()
    assert "## Split: train" in report and "## Split: test" in report
    assert any(p.name.startswith("test_sgbm_worst") for p in (out / "error_maps").iterdir())


def test_evaluate_bad_inputs_exit_2(dataset, tmp_path, capsys):
    def run(*args):
        code = main(["evaluate", *args, "--quiet"])
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
        return err

    assert "manifest.csv" in run(str(tmp_path))
    assert "unknown method" in run(str(dataset.root), "--methods", "sgbm,psmnet")
    assert "nothing to score" in run(str(dataset.root), "--methods", "none")
    preds = tmp_path / "preds"
    preds.mkdir()
    np.save(preds / "000000.npy", np.zeros((dataset.height, dataset.width), np.float32))
    assert "000001.npy" in run(str(dataset.root), "--methods", "none", "--predictions", str(preds))
    for i in (1, 2):
        np.save(preds / f"{i:06d}.npy", np.zeros((4, 4), np.float32))
    assert "shape" in run(str(dataset.root), "--methods", "none", "--predictions", str(preds))
    assert "not found" in run(str(dataset.root), "--methods", "none", "--predictions", str(tmp_path / "nope"))
    assert "--min-depth" in run(str(dataset.root), "--min-depth", "0.1", "--max-depth", "0.05")
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    assert "not a folder" in run(str(dataset.root), "--methods", "gt", "-o", str(blocker))
    _manifest(tmp_path, [{"sequence": "x", "split": "test", "status": "failed"}])
    assert "done" in run(str(tmp_path))
