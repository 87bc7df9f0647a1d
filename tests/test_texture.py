"""Specular highlights out of the capture texture: detection, fill, identity with ``keep``, the mesh folder."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage as ndi

from rgbd2scene.cli import main
from rgbd2scene.files.images import read_image
from rgbd2scene.reconstruct.texture import HighlightSettings, highlight_mask, remove_highlights
from tests.conftest import BUNDLED_SAMPLE

H, W = 240, 320
#: (row, col, core radius px, glow radius px) of the synthetic highlights
SPOTS = ((60, 80, 4, 8), (160, 220, 6, 11), (120, 280, 2, 5))


def tissue(seed: int = 0) -> np.ndarray:
    """Reddish tissue: a smooth shading gradient plus fine mottling, well away from white."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    shade = 0.75 + 0.2 * np.sin(u / 37.0) * np.cos(v / 29.0)
    mottle = ndi.gaussian_filter(rng.standard_normal((H, W)), 1.5) * 0.15
    base = np.array([200.0, 90.0, 80.0])
    return np.clip(base * (shade + mottle)[..., None], 0, 255).round().astype(np.uint8)


def with_highlights(clean: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``clean`` plus white highlights: clipped cores with a glow that fades into the tissue colour.

    Returns the image, the cores and the glows (every pixel the highlights changed).
    """
    v, u = np.mgrid[0:H, 0:W]
    img = clean.astype(np.float64)
    cores, glows = np.zeros((H, W), bool), np.zeros((H, W), bool)
    for row, col, core, glow in SPOTS:
        r = np.hypot(v - row, u - col)
        weight = np.clip((glow - r) / (glow - core), 0.0, 1.0) ** 0.5
        img = img * (1 - weight[..., None]) + 255.0 * weight[..., None]
        cores |= r <= core
        glows |= weight > 0
    return img.round().astype(np.uint8), cores, glows


def test_highlights_are_found_and_filled_from_the_surrounding_colour():
    clean = tissue()
    img, cores, glows = with_highlights(clean)
    out, mask = remove_highlights(img)

    assert mask[cores].all()  # every clipped pixel is found
    # ... and nothing far from a highlight: the mask stays within the glow plus the dilation
    near = ndi.binary_dilation(glows, np.ones((3, 3), bool), iterations=HighlightSettings().dilate_px + 1)
    assert not mask[~near].any()
    assert mask.sum() >= glows.sum() * 0.6  # most of the glow as well, not just the cores

    assert np.array_equal(out[~mask], img[~mask])  # every other pixel untouched
    err = np.abs(out.astype(int) - clean.astype(int))[mask]
    before = np.abs(img.astype(int) - clean.astype(int))[mask]
    print(f"filled {mask.sum()} px: mean abs error {err.mean():.1f}/255 (highlight {before.mean():.1f}), "
          f"95th percentile {np.percentile(err, 95):.0f}")
    assert err.mean() < 12 and np.percentile(err, 95) < 30
    assert err.mean() < 0.15 * before.mean()
    # the fill has the tissue's colour: red dominates, no white left
    assert (out[mask][:, 0] > out[mask][:, 1] + 50).all()


def test_keep_is_the_identity():
    img, _, _ = with_highlights(tissue())
    out, mask = remove_highlights(img, mode="keep")
    assert np.array_equal(out, img) and out is not img
    assert mask.shape == (H, W) and not mask.any()


def test_no_highlight_no_change():
    img = tissue(1)
    out, mask = remove_highlights(img)
    assert not mask.any() and np.array_equal(out, img)


def test_large_white_region_is_an_object_not_a_highlight():
    img = tissue(2)
    img[20:120, 20:180] = 255  # 21 % of the image: a white object (a drape, a wall)
    assert not highlight_mask(img).any()
    assert highlight_mask(img, HighlightSettings(max_region_fraction=0.5))[20:120, 20:180].all()


def test_bad_input():
    with pytest.raises(ValueError, match="uint8"):
        remove_highlights(np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="uint8"):
        remove_highlights(np.zeros((4, 4), np.uint8), mode="keep")
    with pytest.raises(ValueError, match="mode"):
        remove_highlights(tissue(), mode="dim")


@pytest.fixture(scope="module")
def mesh_folders(tmp_path_factory):
    args = ["--rgb", str(BUNDLED_SAMPLE / "rgb.png"), "--depth", str(BUNDLED_SAMPLE / "depth.png"),
            "--camera", str(BUNDLED_SAMPLE / "camera.json"), "--no-overview", "--fill", "inpaint", "--smooth", "none"]
    folders = {}
    for mode in ("remove", "keep"):
        folders[mode] = tmp_path_factory.mktemp(mode)
        assert main(["mesh", *args, "--highlights", mode, "-o", str(folders[mode])]) == 0
    return folders


def test_mesh_folder_texture_and_record(mesh_folders):
    capture = read_image(BUNDLED_SAMPLE / "rgb.png")
    removed, kept = mesh_folders["remove"], mesh_folders["keep"]
    record = json.loads((removed / "scene.json").read_text())
    assert record["options"]["highlights"] == "remove" and record["texture"]["highlights"] == "remove"
    stats = record["texture"]["stats"]
    # the sample's organ is wet: its saturated highlights cover about 1 % of the image, their glow more
    assert 0.01 < stats["highlight_fraction"] < 0.15 and stats["highlight_regions"] > 10
    assert record["files"]["texture_original"] == "texture_original.png"
    assert np.array_equal(read_image(removed / "texture_original.png"), capture)
    texture = read_image(removed / "mesh_texture.png")
    changed = np.any(texture != capture, axis=-1)
    assert 0 < changed.mean() <= stats["highlight_fraction"]
    assert (capture[changed].min(axis=-1) > texture[changed].min(axis=-1)).mean() > 0.9  # less white

    record = json.loads((kept / "scene.json").read_text())
    assert record["texture"]["highlights"] == "keep" and record["texture"]["stats"]["highlight_fraction"] == 0
    assert "texture_original" not in record["files"] and not (kept / "texture_original.png").exists()
    assert np.array_equal(read_image(kept / "mesh_texture.png"), capture)
