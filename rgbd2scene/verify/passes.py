"""``verify --blender-frames N``: the dataset's maps against Blender's own passes of N sampled frames.

The ground truth comes from the scene model (ray casting, ``groundtruth/model_maps.py``); Blender's Depth,
Normal, Vector and Object Index passes of a 1-sample data render through the pixel centres
(``render --gt-source blender``) are an independent second source. The sampled frames are rendered that way
into a scratch folder and compared map by map (:func:`compare_maps`); the rows go under the check
``passes``. Blender renders pinholes: a raw (distorted) dataset is not compared (a note says so).
"""

from __future__ import annotations

import tempfile

import numpy as np

#: Row name -> tolerance of :func:`compare_maps`' figures (float32 ray casts in Blender and Open3D agree to
#: ~1e-6 of the depth; a pixel centre within rounding of a silhouette may fall either way).
PASS_TOLERANCES = {"surface or id differs (px)": 4.0, "depth max rel diff": 1e-5, "normals max angle (deg)": 0.05,
                   "flow max diff (px)": 5e-3, "disparity max rel diff": 1e-5}


def compare_maps(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, float]:
    """Figures of two ground-truth dicts of one eye and frame: pixels whose surface (hit or not, instance id)
    differs, and over the pixels where both see the same surface the largest depth, disparity, normal and flow
    differences. Maps absent from either are left out."""
    out: dict[str, float] = {}
    hit_a, hit_b = np.isfinite(a["depth"]), np.isfinite(b["depth"])
    same = hit_a == hit_b
    if "segmentation" in a and "segmentation" in b:
        same &= a["segmentation"] == b["segmentation"]
    out["surface or id differs (px)"] = float((~same).sum())
    both = same & hit_a
    if not both.any():
        return out
    da, db = a["depth"][both].astype(np.float64), b["depth"][both].astype(np.float64)
    out["depth max rel diff"] = float(np.max(np.abs(da - db) / db))
    if "disparity" in a and "disparity" in b:
        pa, pb = a["disparity"][both].astype(np.float64), b["disparity"][both].astype(np.float64)
        out["disparity max rel diff"] = float(np.max(np.abs(pa - pb) / pb))
    if "normals" in a and "normals" in b:
        cos = np.clip(np.sum(a["normals"][both].astype(np.float64) * b["normals"][both], axis=-1), -1.0, 1.0)
        out["normals max angle (deg)"] = float(np.degrees(np.arccos(cos)).max())
    diffs = []
    for key in ("flow_forward", "flow_backward"):
        if key in a and key in b:
            fa, fb = a[key][both].astype(np.float64), b[key][both].astype(np.float64)
            ok = np.isfinite(fa).all(-1) & np.isfinite(fb).all(-1)
            if (np.isfinite(fa).all(-1) != np.isfinite(fb).all(-1)).any():
                diffs.append(np.inf)  # flow on one side only
            if ok.any():
                diffs.append(np.linalg.norm(fa[ok] - fb[ok], axis=-1).max())
    if diffs:
        out["flow max diff (px)"] = float(max(diffs))
    return out


def sampled_frames(count: int, n: int) -> list[int]:
    """``n`` frames spread evenly over ``count`` (first and last included)."""
    n = max(1, min(int(n), count))
    return sorted({int(round(x)) for x in np.linspace(0, count - 1, n)})


def blender_crosscheck(run, n: int) -> str | None:
    """Render ``n`` sampled frames' passes with Blender and add the ``passes`` rows to ``run``; returns a
    note when the comparison cannot be made (no scene folder, a raw dataset)."""
    from rgbd2scene.dataset import layout as ds
    from rgbd2scene.stages.render import RenderOptions, render_dataset

    dataset = run.dataset
    if not run.rectified:
        return "passes: a raw (distorted) dataset is not compared with Blender's pinhole passes"
    scene_dir = dataset.scene_dir
    if scene_dir is None or not (scene_dir / "scene.blend").is_file():
        return "passes: no scene folder with scene.blend to render the passes from"
    maps = ",".join(dataset.meta.get("render", {}).get("gt", [])) or "all"
    with tempfile.TemporaryDirectory(prefix="rgbd2scene-passes-") as tmp:
        for index in sampled_frames(dataset.frames, n):
            options = RenderOptions(frames=dataset.frames, size=(dataset.width, dataset.height), gt=maps,
                                    start=index, end=index + 1, samples=1, denoise="none", gt_source="blender")
            render_dataset(scene_dir, tmp, options, progress=False)
            for eye in ds.EYES:
                _, ref = ds.read_frame(tmp, eye, index, rgb=False)
                figures = compare_maps(dataset.gt(eye, index), ref)
                for name, value in figures.items():
                    run.collector.add("passes", eye, name, index, value, PASS_TOLERANCES[name])
    return None
