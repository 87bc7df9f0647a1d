"""The built-in instrument (closed meshes, hinge) and its default motion on the bundled sample (no Blender).

The motion is checked independently of how it was made: each part's watertight mesh is placed at its pose
and the tissue's vertices near it are tested for being inside it (Open3D occupancy) and for their distance
to it; the tip is projected into both eyes.
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from rgbd2scene import conventions as cv
from rgbd2scene.capture.camera import load_camera_json
from rgbd2scene.capture.readers import load_capture
from rgbd2scene.geometry.raycast import raycaster
from rgbd2scene.reconstruct.pipeline import MeshOptions, reconstruct
from rgbd2scene.scene.objects.instrument import PART_CLASSES, PARTS, Instrument
from rgbd2scene.scene.objects.motion import MotionOptions, default_motion
from rgbd2scene.scene.paths import make_path
from rgbd2scene.scene.rig import StereoRig
from tests.conftest import BUNDLED_SAMPLE

FRAMES = 40


def _welded_edges(mesh) -> Counter:
    """Directed edges of the mesh after merging coincident vertices."""
    _, index = np.unique(np.round(mesh.vertices / 1e-9).astype(np.int64), axis=0, return_inverse=True)
    t = index.ravel()[mesh.triangles]
    return Counter(map(tuple, np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])))


def _volume(mesh) -> float:
    p = mesh.vertices[mesh.triangles]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


@pytest.mark.parametrize("instrument", [Instrument(), Instrument(shaft_diameter=0.005, jaw_length=0.015,
                                                                 look="metal", segments=12)])
def test_parts_are_closed_with_outward_normals(instrument):
    meshes = instrument.meshes()
    assert tuple(meshes) == PARTS
    for name, mesh in meshes.items():
        edges = _welded_edges(mesh)
        # watertight and consistently wound: every edge once each way
        assert all(count == 1 and edges[(b, a)] == 1 for (a, b), count in edges.items()), name
        assert _volume(mesh) > 0, name  # outward normals
    r = instrument.shaft_radius
    n = instrument.segments  # a prism on the inscribed n-gon
    prism = 0.5 * n * r * r * np.sin(2 * np.pi / n) * instrument.shaft_length
    np.testing.assert_allclose(_volume(meshes["shaft"]), prism, rtol=1e-9)
    assert PART_CLASSES["jaw_upper"] == PART_CLASSES["jaw_lower"] != PART_CLASSES["shaft"]
    assert instrument.materials()["shaft"] == instrument.look and instrument.materials()["jaw_upper"] == "metal"


def test_jaws_turn_about_the_hinge():
    instrument = Instrument()
    closed, opened = instrument.jaw_offsets(0.0), instrument.jaw_offsets(np.radians(60.0))
    end = np.array([0.0, 0.0, instrument.jaw_length, 1.0])
    for name in ("jaw_upper", "jaw_lower"):
        np.testing.assert_allclose((closed[name] @ end)[:3], instrument.tip, atol=1e-12)
        np.testing.assert_allclose(opened[name][:3, 3], instrument.hinge[:3, 3])  # the hinge does not move
    # upper jaw to -y, lower to +y, each by half the opening
    assert (opened["jaw_upper"] @ end)[1] == pytest.approx(-instrument.jaw_length * np.sin(np.radians(30.0)))
    assert (opened["jaw_lower"] @ end)[1] == pytest.approx(instrument.jaw_length * np.sin(np.radians(30.0)))
    with pytest.raises(ValueError, match="shaft_diameter"):
        Instrument(shaft_diameter=0.05)
    with pytest.raises(ValueError, match="look"):
        Instrument(look="gold")


@pytest.fixture(scope="module")
def tissue():
    intr, scale = load_camera_json(BUNDLED_SAMPLE / "camera.json")
    capture = load_capture(BUNDLED_SAMPLE / "rgb.png", BUNDLED_SAMPLE / "depth.png", intr, depth_scale=scale)
    mesh = reconstruct(capture, MeshOptions(overview=False)).mesh
    return mesh, raycaster(mesh.vertices, mesh.triangles)


def _intrusions(mesh, rc_tissue, track, instrument, clearance) -> tuple[int, float]:
    """Tissue vertices inside any part, and the smallest distance from the tissue to any part (metres),
    over all frames, computed with the parts' own closed meshes at their poses."""
    import open3d as o3d

    parts = instrument.meshes()
    poses = track.part_poses(instrument)
    inside, nearest = 0, np.inf
    vertices = rc_tissue.vertices
    for f in range(len(track.poses)):
        # tissue vertices within 3 cm of the shaft's axis near the tissue or of the tip
        tip = track.tip[f]
        axis = cv.transform_points(track.poses[f], np.array([[0.0, 0.0, -0.05]]))[0]
        ab = tip - axis
        s = np.clip((vertices - axis) @ ab / (ab @ ab), 0.0, 1.0)
        near = vertices[np.linalg.norm(vertices - (axis + s[:, None] * ab), axis=1) < 0.03]
        if not len(near):
            continue
        scene = o3d.t.geometry.RaycastingScene()
        for name, part in parts.items():
            posed = cv.transform_points(poses[name][f], part.vertices).astype(np.float32)
            scene.add_triangles(o3d.core.Tensor(posed), o3d.core.Tensor(part.triangles.astype(np.uint32)))
        query = o3d.core.Tensor(near.astype(np.float32))
        inside += int(scene.compute_occupancy(query).numpy().sum())
        nearest = min(nearest, float(scene.compute_distance(query).numpy().min()))
    return inside, nearest


@pytest.mark.parametrize("kind", ["static", "scan", "orbit", "random"])
def test_default_motion_stays_in_view_and_clear_of_the_tissue(tissue, kind):
    mesh, rc = tissue
    rig = StereoRig.endoscope()
    path = make_path(kind, rig=rig, frames=FRAMES, seed=4, rc=rc)
    instrument = Instrument()
    options = MotionOptions()
    track = default_motion(rc, rig, path, instrument, options, seed=4)
    poses = track.part_poses(instrument)
    assert set(poses) == set(PARTS)
    for name, p in poses.items():
        assert p.shape == (FRAMES, 4, 4) and p.dtype == np.float64, name
        rotation = p[:, :3, :3]
        np.testing.assert_allclose(rotation.transpose(0, 2, 1) @ rotation, np.broadcast_to(np.eye(3), rotation.shape),
                                   atol=1e-12)
    # the shaft's axis passes through the trocar at every frame
    to_trocar = track.trocar - track.poses[:, :3, 3]
    along = np.einsum("fi,fi->f", to_trocar, track.poses[:, :3, 2])
    np.testing.assert_allclose(np.linalg.norm(to_trocar, axis=1), np.abs(along), rtol=1e-9)
    # in view: projected into both eyes independently of the motion's own bookkeeping
    intr = rig.intrinsics
    seen = np.zeros(FRAMES, bool)
    for f in range(FRAMES):
        ok = True
        for T in (path.T_world_cam[f], rig.right_pose(path.T_world_cam[f])):
            p = cv.transform_points(cv.invert_pose(T), track.tip[f])
            u, v = cv.project(p, intr.K)
            ok &= bool(p[2] > 0 and 0 <= u <= intr.width - 1 and 0 <= v <= intr.height - 1)
        seen[f] = ok
    print(f"{kind}: tip in both views in {seen.mean():.0%} of {FRAMES} frames (the motion says "
          f"{track.in_view_fraction:.0%}), trocar azimuth {track.settings['trocar_azimuth_deg']:.0f} deg")
    assert seen.mean() >= 0.8 and track.in_view_fraction >= 0.8
    assert not seen[0]  # it enters: outside both views at the first frame
    assert seen[track.settings["entry_frames"]:].all()
    # never through the tissue
    inside, nearest = _intrusions(mesh, rc, track, instrument, options.clearance)
    assert inside == 0
    assert nearest > 0.5 * options.clearance, nearest
    # jaws open and close within the opening asked for
    assert 0.0 <= track.jaw_angle.min() and track.jaw_angle.max() <= np.radians(options.jaw_open_deg) + 1e-12
    assert np.ptp(track.jaw_angle) > np.radians(10.0)


def test_default_motion_is_seeded(tissue):
    _, rc = tissue
    rig = StereoRig.endoscope(128, 64)
    path = make_path("scan", rig=rig, frames=12, seed=0, rc=rc)
    a = default_motion(rc, rig, path, Instrument(), seed=7)
    b = default_motion(rc, rig, path, Instrument(), seed=7)
    c = default_motion(rc, rig, path, Instrument(), seed=8)
    np.testing.assert_array_equal(a.poses, b.poses)
    assert not np.allclose(a.poses, c.poses)
