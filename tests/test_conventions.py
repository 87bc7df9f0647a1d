import numpy as np

from rgbd2scene import conventions as cv
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.scene.paths import look_at

K = Intrinsics(64, 32, 40.0, 45.0, 30.0, 17.0).K


def test_backproject_project_round_trip():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.02, 0.2, (32, 64))
    pts = cv.backproject(depth, K)
    u, v = cv.project(pts, K)
    uu, vv = cv.pixel_grid(32, 64)
    assert np.allclose(u, uu, atol=1e-9) and np.allclose(v, vv, atol=1e-9)
    assert np.allclose(pts[..., 2], depth)


def test_principal_point_pixel_back_projects_on_axis():
    depth = np.full((32, 64), 0.1)
    pts = cv.backproject(depth, Intrinsics.from_fov(64, 32, 60.0).K)
    # cx = (W-1)/2 lies between the two central columns: they are symmetric about the axis
    assert np.isclose(pts[0, 31, 0], -pts[0, 32, 0])


def test_blender_pose_round_trip_and_axes():
    T = look_at([0.01, 0.02, -0.03], [0.0, 0.0, 0.1])
    Tb = cv.blender_pose_from_opencv(T)
    assert np.allclose(cv.opencv_pose_from_blender(Tb), T)
    # Blender camera looks down its -Z: the OpenCV +z axis
    assert np.allclose(-Tb[:3, 2], T[:3, 2])
    assert np.allclose(Tb[:3, 1], -T[:3, 1])


def test_disparity_depth_inverse_and_nan():
    depth = np.array([[0.05, np.nan, 0.1]], dtype=np.float32)
    d = cv.disparity_from_depth(depth, 400.0, 0.005)
    assert np.isclose(d[0, 0], 400 * 0.005 / 0.05) and np.isnan(d[0, 1])
    assert np.allclose(cv.depth_from_disparity(d, 400.0, 0.005), depth, equal_nan=True)


def test_flow_between_cameras_translation_closed_form():
    z = 0.08
    depth = np.full((32, 64), z)
    Ta = np.eye(4)
    Tb = np.eye(4)
    Tb[0, 3] = 0.002  # camera moves right: the scene moves left in the image
    flow = cv.flow_between_cameras(depth, K, Ta, Tb)
    assert np.allclose(flow[..., 0], -K[0, 0] * 0.002 / z, atol=1e-6)
    assert np.allclose(flow[..., 1], 0.0, atol=1e-6)


def test_blender_vector_to_flow_signs():
    vec = np.zeros((2, 2, 4), dtype=np.float32)
    vec[..., 0], vec[..., 1], vec[..., 2], vec[..., 3] = 1.0, 2.0, 3.0, 4.0
    fwd, bwd = cv.flow_from_blender_vector(vec)
    assert np.all(fwd[..., 0] == -3.0) and np.all(fwd[..., 1] == 4.0)
    assert np.all(bwd[..., 0] == 1.0) and np.all(bwd[..., 1] == -2.0)


def test_orient_normals_to_camera():
    rays = cv.pixel_rays(4, 4, Intrinsics.from_fov(4, 4, 60).K)
    n = np.zeros((4, 4, 3))
    n[..., 2] = 1.0  # facing away
    out = cv.orient_normals_to_camera(n, rays)
    assert np.all(np.sum(out * rays, axis=-1) < 0)


def test_image_area_is_half_a_pixel_beyond_the_outer_pixel_centres():
    assert cv.image_bounds(4, 3) == (-0.5, 3.5, -0.5, 2.5)
    u = np.array([-0.5, -0.5001, 3.4999, 3.5, 1.0, np.nan])
    v = np.array([0.0, 0.0, 2.4999, 0.0, 2.5, 1.0])
    np.testing.assert_array_equal(cv.in_image(u, v, 4, 3), [True, False, True, False, False, False])
