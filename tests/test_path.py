"""Camera paths (look_at, waypoints, generated scan/orbit/random paths, path files) and the raycaster."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rgbd2scene.conventions import backproject, project, transform_points
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.geometry.mesh import vertex_normals
from rgbd2scene.geometry.raycast import raycaster
from rgbd2scene.scene.paths import (
    PATH_GENERATORS,
    PATH_KINDS,
    CameraPath,
    Placement,
    Track,
    load_path_file,
    look_at,
    make_path,
    path_coverage,
    save_path_file,
    waypoint_path,
)
from rgbd2scene.scene.rig import StereoRig
from rgbd2scene.stages.scene import SceneOptions, make_description

KINECT_K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])


def grid_triangles(h, w):
    idx = np.arange(h * w).reshape(h, w)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    return np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                           np.stack([b, c, d], -1).reshape(-1, 3)]).astype(np.int32)


def kinect_tissue(step=4):
    """A bumpy tissue-like surface filling a 640x480 Kinect view at about 0.6 m (every step-th pixel)."""
    v, u = np.mgrid[0:480:step, 0:640:step].astype(float)
    z = (0.6 + 0.03 * np.sin(u / 45.0) * np.cos(v / 37.0) + 0.008 * np.sin(u / 11.0 + v / 15.0)
         + 0.05 * (u - 320) / 640)
    x = (u - KINECT_K[0, 2]) * z / KINECT_K[0, 0]
    y = (v - KINECT_K[1, 2]) * z / KINECT_K[1, 1]
    pts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    return pts, grid_triangles(*u.shape)


@pytest.fixture(scope="module")
def tissue():
    v, t = kinect_tissue()
    return v, t, raycaster(v, t)


# ------------------------------------------------------------------------------------------ raycaster


def test_raycaster_plane_exact_pixel_centres():
    # A tilted plane; a camera looking at it from an oblique pose.
    n = np.array([0.2, -0.1, -1.0])
    n /= np.linalg.norm(n)
    p0 = np.array([0.0, 0.0, 0.05])
    e1 = np.cross(n, [0, 1, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    corners = np.array([p0 + s * e1 + r * e2 for s, r in ((-1, -1), (1, -1), (-1, 1), (1, 1))])
    tris = np.array([[0, 2, 1], [1, 2, 3]])
    rc = raycaster(corners, tris)
    rig = StereoRig.endoscope(40, 20)
    K = rig.intrinsics.K
    T = look_at([0.003, -0.002, 0.0], p0 + [0.004, 0.001, 0], [0.1, -1, 0])
    out = rc.cast(Camera.pinhole(K, 40, 20), T)
    assert out["depth"].dtype == np.float32 and out["normals_cam"].dtype == np.float32
    assert out["triangle_ids"].dtype == np.int64 and np.isfinite(out["depth"]).all()
    # back-projected pixel centres lie on the plane
    pts_world = transform_points(T, backproject(out["depth"], K))
    assert np.abs((pts_world - p0) @ n).max() < 1e-7
    # and project back onto the integer pixel centres (the project's convention, not +0.5)
    u, v = project(transform_points(np.linalg.inv(T), pts_world), K)
    uu, vv = np.meshgrid(np.arange(40), np.arange(20))
    assert np.abs(u - uu).max() < 1e-3 and np.abs(v - vv).max() < 1e-3
    # normals in the camera frame, facing the camera
    n_cam = T[:3, :3].T @ n
    n_cam = n_cam if n_cam[2] < 0 else -n_cam
    assert np.abs(out["normals_cam"] - n_cam).max() < 1e-5
    miss = rc.cast(Camera.pinhole(K, 40, 20), look_at([0, 0, 0], [0, 0, -1]))
    assert np.isnan(miss["depth"]).all() and (miss["triangle_ids"] == -1).all()
    assert np.isnan(miss["normals_cam"]).all()


def test_smooth_normals_interpolate_vertex_normals():
    v, t = kinect_tissue(step=16)
    rc = raycaster(v, t)
    vn = vertex_normals(v, t, "angle")
    assert np.allclose(np.linalg.norm(vn, axis=1), 1.0)
    T = look_at([0.0, 0.0, 0.55], [0.0, 0.0, 0.6])
    K = StereoRig.endoscope(32, 16).intrinsics.K
    out = rc.cast(Camera.pinhole(K, 32, 16), T, normals="smooth", with_uvs=True)
    ids, uvs = out["triangle_ids"], out["uvs"]
    ok = ids >= 0
    tri = t[ids[ok]]
    n = ((1 - uvs[ok].sum(-1))[:, None] * vn[tri[:, 0]] + uvs[ok][:, :1] * vn[tri[:, 1]]
         + uvs[ok][:, 1:] * vn[tri[:, 2]])
    n = n / np.linalg.norm(n, axis=1, keepdims=True) @ T[:3, :3]
    n *= -np.sign(n[:, 2:3])
    assert np.abs(out["normals_cam"][ok] - n).max() < 1e-5


# ------------------------------------------------------------------------------------------ look_at, waypoints


def test_look_at_axes():
    assert np.allclose(look_at([0, 0, 0], [0, 0, 1]), np.eye(4))
    T = look_at([0.1, 0.2, 0.3], [0.0, -0.1, 0.9])
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    d = np.array([0.0, -0.1, 0.9]) - [0.1, 0.2, 0.3]
    assert np.allclose(R[:, 2], d / np.linalg.norm(d))
    assert abs(R[:, 0] @ [0, -1, 0]) < 1e-12  # x stays horizontal
    u, v = project(transform_points(np.linalg.inv(T), np.array([0.0, -0.1, 0.9])), KINECT_K)
    assert np.isclose(u, KINECT_K[0, 2]) and np.isclose(v, KINECT_K[1, 2])


def test_waypoints_pass_through_and_are_smooth():
    wps = [{"position": [0, 0, 0], "look_at": [0, 0, 1]},
           {"position": [0.01, 0.005, 0.002], "look_at": [0.02, 0, 1]},
           {"position": [0.02, -0.004, 0.0], "look_at": [0.03, 0.02, 0.9]},
           {"position": [0.03, 0.0, 0.003], "look_at": [0.01, 0, 1]}]
    path = waypoint_path(wps, frames=31, fps=25)
    assert path.frames == 31 and path.fps == 25 and path.kind == "waypoints"
    for i, w in zip((0, 10, 20, 30), wps, strict=True):
        assert np.allclose(path.T_world_cam[i], look_at(w["position"], w["look_at"]), atol=1e-12)
    pos = path.T_world_cam[:, :3, 3]
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    assert np.abs(np.diff(pos, 2, axis=0)).max() < 0.3 * step.max()  # no jumps
    # full poses with explicit frames: rotation spline through the keys
    poses = [look_at([0, 0, 0], [0, 0, 1]), look_at([0.01, 0, 0], [0.05, 0.0, 1]),
             look_at([0.02, 0.01, 0], [0.0, 0.05, 1], up=[0.3, -1, 0])]
    wp2 = [{"T_world_cam": poses[0].tolist(), "frame": 0}, {"T_world_cam": poses[1], "frame": 7},
           {"T_world_cam": poses[2].tolist(), "frame": 19}]
    path = waypoint_path(wp2, frames=25)
    for f, T in zip((0, 7, 19), poses, strict=True):
        assert np.allclose(path.T_world_cam[f], T, atol=1e-9)
    assert np.allclose(path.T_world_cam[19:], poses[2], atol=1e-9)  # held after the last key
    R = path.T_world_cam[:, :3, :3]
    assert np.allclose(np.einsum("fji,fjk->fik", R, R), np.eye(3), atol=1e-9)
    # a single waypoint: a static camera
    assert np.allclose(waypoint_path([poses[1]], 5).T_world_cam, poses[1])


def test_path_file_roundtrip_and_errors(tmp_path):
    good = tmp_path / "path.json"
    good.write_text(json.dumps({"fps": 24, "frames": 9, "waypoints": [
        {"position": [0, 0, 0], "look_at": [0, 0, 1]},
        {"T_world_cam": look_at([0.01, 0, 0], [0.01, 0, 1]).tolist()}]}))
    path = load_path_file(good)
    assert path.frames == 9 and path.fps == 24
    assert np.allclose(path.T_world_cam[-1], look_at([0.01, 0, 0], [0.01, 0, 1]))
    out = tmp_path / "saved.json"
    save_path_file(out, path)
    again = load_path_file(out)
    assert np.allclose(again.T_world_cam, path.T_world_cam, atol=1e-12) and again.fps == 24
    assert make_path("waypoints", waypoints=str(good)).frames == 9

    bad_cases = {
        "missing.json": None,
        "notjson.json": "{not json",
        "list.json": "[1, 2]",
        "nowp.json": {"fps": 30, "frames": 10},
        "emptywp.json": {"waypoints": []},
        "frames.json": {"frames": 0, "waypoints": [{"position": [0, 0, 0], "look_at": [0, 0, 1]}]},
        "fps.json": {"fps": -1, "waypoints": [{"position": [0, 0, 0], "look_at": [0, 0, 1]}]},
        "nolook.json": {"waypoints": [{"position": [0, 0, 0]}]},
        "short.json": {"waypoints": [{"position": [0, 0], "look_at": [0, 0, 1]}]},
        "same.json": {"waypoints": [{"position": [0, 0, 1], "look_at": [0, 0, 1]}]},
        "pose.json": {"waypoints": [{"T_world_cam": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}]},
        "scaled.json": {"waypoints": [{"T_world_cam": (2 * np.eye(4)).tolist()}]},
        "order.json": {"frames": 10, "waypoints": [{"position": [0, 0, 0], "look_at": [0, 0, 1], "frame": 5},
                                                   {"position": [0, 0, 0], "look_at": [0, 0, 1], "frame": 2}]},
        "unknown.json": {"waypoint": []},
    }
    for name, content in bad_cases.items():
        p = tmp_path / name
        if content is not None:
            p.write_text(content if isinstance(content, str) else json.dumps(content))
        with pytest.raises(ValueError) as exc:
            load_path_file(p)
        assert str(p) in str(exc.value), (name, str(exc.value))


def test_track_of_any_object_and_the_camera_json_format(tmp_path):
    poses = np.stack([look_at([0.01 * i, 0, 0], [0.01 * i, 0, 1]) for i in range(3)])
    path = CameraPath(poses, fps=25.0, kind="test", settings={"a": 1})
    d = path.to_dict()
    assert list(d) == ["kind", "fps", "frames", "settings", "T_world_cam"] and d["frames"] == 3
    again = CameraPath.from_dict(json.loads(json.dumps(d)))
    assert type(again) is CameraPath and np.array_equal(again.T_world_cam, poses)
    assert again.fps == 25.0 and again.kind == "test" and again.settings == {"a": 1}
    # frames before the first and after the last hold the end poses
    assert np.array_equal(path.pose_at(-2), poses[0]) and np.array_equal(path.pose_at(1), poses[1])
    assert np.array_equal(path.pose_at(7), poses[2])
    # an instrument's track through waypoints (a T_world_obj pose and a look-at), saved and reloaded
    end = look_at([0.02, 0.01, 0.0], [0.0, 0.0, 0.05])
    keys = [{"T_world_obj": poses[0].tolist(), "frame": 0},
            {"position": [0.02, 0.01, 0.0], "look_at": [0.0, 0.0, 0.05], "frame": 4}]
    track = waypoint_path(keys, frames=6, fps=10, track_type=Track)
    assert type(track) is Track and "T_world_obj" in track.to_dict() and "T_world_cam" not in track.to_dict()
    assert np.allclose(track.pose_at(0), poses[0], atol=1e-12) and np.allclose(track.pose_at(5), end, atol=1e-12)
    save_path_file(tmp_path / "tool.json", track)
    assert "T_world_obj" in (tmp_path / "tool.json").read_text()
    reloaded = load_path_file(tmp_path / "tool.json", track_type=Track)
    assert np.allclose(reloaded.poses, track.poses, atol=1e-12) and reloaded.fps == 10
    with pytest.raises(ValueError, match="T_world_obj"):  # an object's pose key is not the camera's
        waypoint_path([{"T_world_cam": poses[0].tolist()}], 2, track_type=Track)


# ------------------------------------------------------------------------------------------ generated paths


@pytest.mark.parametrize("kind", ["scan", "orbit", "random"])
def test_generated_paths_keep_standoff_and_coverage(tissue, kind):
    v, t, rc = tissue
    rig = StereoRig.endoscope()
    path = make_path(kind, v, t, rig, frames=24, fps=30, seed=3, rc=rc, check_scale=0.25)
    assert isinstance(path, CameraPath) and path.kind == kind and path.T_world_cam.shape == (24, 4, 4)
    R = path.T_world_cam[:, :3, :3]
    assert np.allclose(np.einsum("fji,fjk->fik", R, R), np.eye(3), atol=1e-9)
    standoff = rc.centre_depth(path.T_world_cam)
    assert np.all(np.abs(standoff - 0.04) <= 0.2 * 0.04), standoff
    assert np.all(R[:, 2, 2] > np.cos(np.radians(40)))  # looks roughly along +z
    cov = path_coverage(v, t, rig, path, rc=rc)
    assert cov.shape == (24, 2) and cov.min() >= 0.95, cov.min(axis=0)
    step = np.linalg.norm(np.diff(path.T_world_cam[:, :3, 3], axis=0), axis=1)
    assert step.max() < 0.01  # smooth: no jumps of a centimetre between frames
    json.dumps(path.to_dict())  # settings are JSON-serialisable


def test_generated_paths_deterministic(tissue):
    v, t, rc = tissue
    rig = StereoRig.endoscope()
    kw = dict(frames=12, fps=30, rc=rc, check_scale=0.2)
    a = make_path("random", v, t, rig, seed=7, **kw)
    b = make_path("random", v, t, rig, seed=7, **kw)
    c = make_path("random", v, t, rig, seed=8, **kw)
    assert np.array_equal(a.T_world_cam, b.T_world_cam) and a.settings == b.settings
    assert not np.allclose(a.T_world_cam, c.T_world_cam)
    s = make_path("static", v, t, rig, frames=3, rc=rc, standoff=0.03, check_scale=0.2)
    assert np.allclose(s.T_world_cam, s.T_world_cam[0]) and np.isclose(rc.centre_depth(s.T_world_cam[0]), 0.03)


def test_make_path_errors(tissue):
    v, t, rc = tissue
    with pytest.raises(ValueError, match="unknown path kind"):
        make_path("zigzag", v, t)
    with pytest.raises(ValueError, match="standoff"):
        make_path("scan", v, t, standoff=-1, rc=rc)
    with pytest.raises(ValueError, match="unknown option"):
        make_path("orbit", v, t, rc=rc, wobble=3)
    with pytest.raises(ValueError, match="waypoints"):
        make_path("waypoints")
    # a mesh much smaller than the view at the standoff
    small = v * [0.02, 0.02, 1.0]
    with pytest.raises(ValueError, match="standoff"):
        make_path("scan", small, t, frames=5, check_scale=0.2)


def test_a_path_kind_is_one_generator_in_the_registry(tissue, monkeypatch):
    v, t, rc = tissue
    assert PATH_KINDS == (*PATH_GENERATORS, "waypoints")
    reliefs = []

    def hover_path(ctx, rng, *, lift=0.0):
        """Hovers over the most interior point; finds no room below a relief allowance of 2."""
        reliefs.append(ctx.relief)
        region = ctx.region(0.0)
        if ctx.relief < 2.0 or not region.any():
            return None
        x, y = ctx.surface.most_interior(region)
        z = ctx.surface.height_at(np.array([[x, y]]))[0] - ctx.standoff - lift
        return Placement(np.tile(look_at([x, y, z], [x, y, 1.0]), (ctx.frames, 1, 1)), {"lift": lift})

    monkeypatch.setitem(PATH_GENERATORS, "hover", hover_path)
    rig = StereoRig.endoscope()
    path = make_path("hover", rig=rig, frames=4, rc=rc, check_scale=0.2, lift=0.005)
    assert path.kind == "hover" and path.T_world_cam.shape == (4, 4, 4)
    assert reliefs == [1.25, 1.6, 2.0]  # retried with larger allowances, stopped at the first that covers
    assert path.settings["lift"] == 0.005 and path.settings["relief_allowance"] == 2.0
    assert path.settings["coverage_min"] >= 0.95 and path.settings["seed"] == 0
    assert np.isclose(rc.centre_depth(path.T_world_cam[0]), 0.045)
    with pytest.raises(ValueError, match="unknown option.*'hover': tilt"):
        make_path("hover", rig=rig, rc=rc, tilt=3)


def test_scene_stage_reports_path_errors_as_user_errors(tissue, tmp_path):
    v, t, rc = tissue
    with pytest.raises(UserError, match=r"^path: standoff must be positive, got -1.0$"):
        make_description(v, t, SceneOptions(standoff=-1.0), rc=rc)
    bad = tmp_path / "bad.json"
    bad.write_text("[1]")
    with pytest.raises(UserError) as exc:
        make_description(v, t, SceneOptions(path_file=str(bad)), rc=rc)
    assert str(exc.value).startswith(f"{bad}: a path file must hold a JSON object")


def test_the_light_keeps_its_power_over_the_working_distance(tissue, tmp_path):
    """Beyond 8 cm the scope light grows with the square of the distance the path looks at (a twin of a capture
    taken from afar); nearer, it is the power asked for; --no-light-for-distance keeps it as asked."""
    v, t, rc = tissue
    near = make_description(v, t, SceneOptions(standoff=0.04, frames=3), rc=rc)
    assert near.light.power_w == SceneOptions().light_power_w
    far_pose = np.eye(4)
    far_pose[2, 3] = float(np.median(v[:, 2])) - 0.5  # the camera 50 cm in front of the surface
    path_file = tmp_path / "far.json"
    path_file.write_text(json.dumps({"fps": 10, "frames": 2, "waypoints": [{"frame": 0, "T_world_cam":
                                                                            far_pose.tolist()}]}))
    far = make_description(v, t, SceneOptions(path_file=str(path_file)), rc=rc)
    distance = rc.centre_depth(far.path.T_world_cam[0])
    assert 0.45 < distance < 0.55
    np.testing.assert_allclose(far.light.power_w, SceneOptions().light_power_w * (distance / 0.08) ** 2, rtol=1e-6)
    fixed = make_description(v, t, SceneOptions(path_file=str(path_file), light_for_distance=False), rc=rc)
    assert fixed.light.power_w == SceneOptions().light_power_w
