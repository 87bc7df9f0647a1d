"""Ray casting the model: casting only the triangles in view gives the hits of the whole mesh."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd2scene.files.meshio import write_ply
from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.geometry.raycast import Raycaster, TriangleBlocks, triangles_in_view
from rgbd2scene.groundtruth.scene_geometry import SceneGeometry
from rgbd2scene.scene.deformation import Deformation
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object
from rgbd2scene.scene.paths import CameraPath, look_at
from rgbd2scene.scene.rig import StereoRig

INTR = Intrinsics(48, 32, 40.0, 40.0, 23.5, 15.5)


def _wavy_grid(n: int = 121, half: float = 0.2) -> Mesh:
    """A bumpy surface much larger than the camera's view (z about 0.1 m, facing the origin)."""
    xs = np.linspace(-half, half, n)
    x, y = np.meshgrid(xs, xs)
    z = 0.1 + 0.01 * np.sin(40 * x) * np.cos(30 * y)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return Mesh(vertices=np.stack([x, y, z], -1).reshape(-1, 3), triangles=tris.astype(np.int32),
                vertex_colors=np.full((n * n, 3), 150, np.uint8))


def _poses() -> list[np.ndarray]:
    return [look_at(np.array([0.03 * i, -0.02, 0.0]), np.array([0.03 * i + 0.01, 0.0, 0.1])) for i in range(3)]


def test_casting_the_triangles_in_view_hits_what_the_whole_mesh_hits():
    mesh = _wavy_grid()
    full = Raycaster(mesh.vertices, mesh.triangles)
    for pose in _poses():
        subset = triangles_in_view(mesh.vertices, mesh.triangles, [(Camera(INTR), pose)])
        assert 0 < len(subset) < 0.2 * len(mesh.triangles)  # the view is a small part of the surface
        culled = Raycaster(mesh.vertices, mesh.triangles, subset)
        a = full.cast(Camera(INTR), pose, normals="smooth", with_uvs=True)
        b = culled.cast(Camera(INTR), pose, normals="smooth", with_uvs=True)
        assert (a["triangle_ids"] >= 0).all()
        for key in ("triangle_ids", "depth", "uvs", "normals_cam"):  # ids of the whole mesh, its vertex normals
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_a_triangle_across_the_view_is_kept_and_one_behind_the_camera_is_not():
    # corners far outside the image on all sides, the triangle itself covering the view
    vertices = np.array([[-1.0, -1.0, 0.1], [1.0, -1.0, 0.1], [0.0, 1.0, 0.1],
                         [0.0, 0.0, -0.1], [0.01, 0.0, -0.1], [0.0, 0.01, -0.1]])
    triangles = np.array([[0, 1, 2], [3, 4, 5]])
    kept = triangles_in_view(vertices, triangles, [(Camera(INTR), np.eye(4))])
    np.testing.assert_array_equal(kept, [0])


def test_blocks_keep_the_triangles_the_corner_test_keeps():
    # a moved, shuffled copy of the grid: blocks of scattered triangles, and of coherent ones (the sorted half)
    rng = np.random.default_rng(3)
    mesh = _wavy_grid()
    every = np.arange(len(mesh.triangles))
    order = np.concatenate([every[::2], rng.permutation(every[1::2])])
    triangles = mesh.triangles[order]
    angle = 0.3
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    pose[:3, 3] = (0.01, -0.02, 0.005)
    world = mesh.vertices @ pose[:3, :3].T + pose[:3, 3]
    blocks = TriangleBlocks(mesh.vertices, triangles, size=16)
    cameras = (Camera(INTR), Camera(Intrinsics(48, 32, 30.0, 30.0, 23.5, 15.5), (0.3, -0.1, 0.001, 0.002)))
    for pose_cam in _poses() + [look_at(np.array([0.0, 0.0, 0.3]), np.array([0.0, 0.0, 0.0]))]:
        for camera in cameras:
            views = [(camera, pose_cam), (camera, pose_cam @ np.diag([1.0, -1.0, -1.0, 1.0]))]
            expected = triangles_in_view(world, triangles, views)
            assert 0 < len(expected) < 0.5 * len(triangles)
            np.testing.assert_array_equal(blocks.in_view(world, triangles, views, pose), expected)
            # vertices moved by up to 2 mm (a deformation): blocks grown by as much keep the same triangles
            moved = world + rng.uniform(-1, 1, world.shape) * 0.002 / np.sqrt(3)
            np.testing.assert_array_equal(blocks.in_view(moved, triangles, views, pose, grow=0.002),
                                          triangles_in_view(moved, triangles, views))


@pytest.mark.parametrize("breathing", [True, False], ids=["deforming", "static"])
def test_scene_geometry_casts_from_its_eyes_as_from_the_whole_scene(tmp_path, breathing):
    # the culled caster's smooth normals come from the triangles around those in view only: the same bits
    mesh = _wavy_grid()
    write_ply(tmp_path / "mesh.ply", mesh)
    tissue = tissue_object("as_captured", texture=None)
    if breathing:
        tissue.parts[0].deformation = Deformation.preset("breathing", amplitude_m=0.004, frequency_hz=1.0,
                                                         extent_m=0.05, centre=(0.03, 0.0, 0.1))
    description = SceneDescription(StereoRig.parallel(INTR, 0.004, clip_start=0.001, clip_end=2.0),
                                   CameraPath(np.stack(_poses()), fps=10.0, kind="test"), Light(), [tissue])
    geometry = SceneGeometry(description, tmp_path)
    for frame in range(3):
        whole = Raycaster(geometry.vertices(frame), geometry.triangles)
        for eye in ("left", "right"):
            T = description.camera_pose(frame, eye)
            a = whole.cast(Camera(INTR), T, normals="smooth", with_uvs=True)
            b = geometry.cast(frame, Camera(INTR), T)
            for key in ("triangle_ids", "depth", "uvs", "normals_cam"):
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"{key}, frame {frame}, {eye}")
    assert len(geometry._cache) <= 3


def test_view_support_keeps_every_triangle_around_what_is_in_view(tmp_path):
    mesh = _wavy_grid()
    write_ply(tmp_path / "mesh.ply", mesh)
    description = SceneDescription(StereoRig.parallel(INTR, 0.004, clip_start=0.001, clip_end=2.0),
                                   CameraPath(np.stack(_poses()), fps=10.0, kind="test"), Light(),
                                   [tissue_object("as_captured", texture=None)])
    geometry = SceneGeometry(description, tmp_path)
    tri = geometry.meshes[0].triangles
    for frame in range(3):
        kept = np.zeros(len(mesh.vertices), bool)
        kept[geometry.view_support(0, frame, Camera(INTR))] = True
        assert 0 < kept.sum() < 0.2 * len(kept)
        eyes = [description.camera_pose(frame, eye) for eye in ("left", "right")]
        in_view = tri[triangles_in_view(geometry.vertices(frame), tri, [(Camera(INTR), e) for e in eyes])]
        touching = np.isin(tri, in_view).any(axis=1)  # triangles sharing a vertex with one in view
        assert kept[tri[touching]].all()


def test_smooth_normals_face_the_camera_with_the_bits_of_side_then_orient():
    """``_facing`` (no face normals in the camera frame except where n . ray is zero or NaN) gives the bits of
    the formula it replaces: the smooth normal turned to its triangle's seen side, then to the camera."""
    from rgbd2scene.conventions import orient_normals_to_camera, rotate
    from rgbd2scene.geometry.raycast import _facing, _side

    rng = np.random.default_rng(3)
    shape = (40, 50)
    rays = np.concatenate([rng.normal(0, 0.4, shape + (2,)), np.ones(shape + (1,))], axis=-1)
    smooth = rng.normal(size=shape + (3,))
    face = rng.normal(size=shape + (3,))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    # exact zeros of n . ray (a normal across the ray in x: (-ray_y, ray_x, 0) . ray = 0 exactly), NaN hits, -0
    smooth[:5, :, 0], smooth[:5, :, 1], smooth[:5, :, 2] = -rays[:5, :, 1], rays[:5, :, 0], 0.0
    smooth[5:7], face[5:7] = np.nan, np.nan
    smooth[7, :, 2] = -0.0
    assert (np.sum(smooth[:5] * rays[:5], axis=-1) == 0).all()
    face_cam = rotate(R.T, face)
    expected = orient_normals_to_camera(smooth * _side(face_cam, rays), rays)
    got = _facing(smooth, rays, face, R)
    assert got.tobytes() == expected.tobytes()
    assert (np.sign(got[:5]) != np.sign(smooth[:5])).any() and (np.sign(got[:5]) == np.sign(smooth[:5])).any()
