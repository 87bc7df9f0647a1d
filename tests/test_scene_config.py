"""The scene configuration file, user meshes and tracked frames (no Blender); bad files through the CLI.

Errors are checked as users see them: ``rgbd2scene scene`` run as a subprocess exits 2 with one ``error:``
line naming the file and the key.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rgbd2scene.files.meshio import read_ply, write_ply
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.geometry.raycast import raycaster
from rgbd2scene.scene.config import ConfigError, load_scene_config, parse_scene_config
from rgbd2scene.scene.deformation import Deformation, rest_normals
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object
from rgbd2scene.scene.objects.assemble import Tissue, add_objects
from rgbd2scene.scene.objects.imported import keyframe_poses, read_mesh_file, rigid_pose
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig
from tests.conftest import flat_grid

CAPTURE = Intrinsics(40, 30, 30.0, 30.0, 19.5, 14.5)
PLANE_Z = 0.05


def _grid_plane(n: int = 21, half: float = 0.06) -> Mesh:
    """A flat grid at z = PLANE_Z facing the capture camera at the origin."""
    return flat_grid(PLANE_Z, half, n, grey=140)


def _box_file(folder: Path, name: str = "box.stl", size_mm: float = 4.0) -> Path:
    import trimesh

    path = folder / name
    trimesh.creation.box((size_mm,) * 3).export(path)
    return path


# ------------------------------------------------------------------------------------- poses and meshes

def test_rotation_spellings_agree():
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("xyz", [10, -20, 30], degrees=True)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.as_matrix(), [0.01, 0.02, 0.03]
    position = [0.01, 0.02, 0.03]
    for pose in (rigid_pose(matrix=T.tolist()), rigid_pose(position=position, quaternion=R.as_quat()),
                 rigid_pose(position=position, euler_deg=[10, -20, 30]),
                 rigid_pose(position=position, rotation=R.as_matrix().tolist())):
        np.testing.assert_allclose(pose, T, atol=1e-12)
    sheared = T.copy()
    sheared[0, 1] += 0.1
    for bad, match in ((dict(matrix=sheared), "not a proper rotation"), (dict(quaternion=[0, 0, 0, 2]), "unit"),
                       (dict(matrix=np.eye(3)), "4x4"), (dict(matrix=T, position=[0, 0, 0]), "not both")):
        with pytest.raises(ValueError, match=match):
            rigid_pose(**bad, where="objects[0].pose")


def test_keyframes_interpolate_with_the_waypoint_machinery():
    """Two keys: linear translation (1 mm per frame exactly) and slerp; held outside the keys."""
    from scipy.spatial.transform import Rotation

    start, end = rigid_pose(position=[0, 0, 0.05]), rigid_pose(position=[0.004, 0, 0.05], euler_deg=[0, 0, 40])
    poses = keyframe_poses([(1, start), (5, end)], frames=8, fps=30.0, where="k")
    assert poses.shape == (8, 4, 4)
    np.testing.assert_allclose(poses[1:6, 0, 3], 0.001 * np.arange(5), atol=1e-15)
    np.testing.assert_allclose(poses[0], start) and np.testing.assert_allclose(poses[7], end, atol=1e-12)
    angle = Rotation.from_matrix(poses[3, :3, :3]).as_euler("xyz", degrees=True)[2]
    assert angle == pytest.approx(20.0)
    with pytest.raises(ValueError, match="increase"):
        keyframe_poses([(5, start), (1, end)], frames=8, fps=30.0, where="k")


def test_mesh_files_in_metres_with_colours_and_textures(tmp_path):
    import trimesh
    from PIL import Image

    box = trimesh.creation.box((10.0, 20.0, 30.0))
    box.export(tmp_path / "box.stl")
    stl = read_mesh_file(tmp_path / "box.stl", scale=0.001)
    np.testing.assert_allclose(np.ptp(stl.mesh.vertices, axis=0), [0.01, 0.02, 0.03])
    assert stl.texture is None and stl.mesh.uvs is None
    textured = box.copy()
    image = np.zeros((8, 8, 3), np.uint8)
    image[:, :, 0] = 200
    textured.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((len(box.vertices), 2)),
                                                    image=Image.fromarray(image))
    for name in ("t.obj", "t.glb"):
        textured.export(tmp_path / name)
        loaded = read_mesh_file(tmp_path / name, recenter=True)
        assert loaded.mesh.uvs is not None and loaded.texture.shape == (8, 8, 3), name
        assert (loaded.texture[..., 0] == 200).all()
        np.testing.assert_allclose(loaded.mesh.vertices.min(axis=0), -loaded.mesh.vertices.max(axis=0), atol=1e-9)
    coloured = box.copy()
    coloured.visual.vertex_colors = np.tile([10, 200, 30, 255], (len(box.vertices), 1))
    coloured.export(tmp_path / "c.ply")
    assert (read_mesh_file(tmp_path / "c.ply").mesh.vertex_colors == [10, 200, 30]).all()
    (tmp_path / "bad.obj").write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match="bad.obj"):
        read_mesh_file(tmp_path / "bad.obj")


# ------------------------------------------------------------------------------------- configuration

CONFIG_TOML = """
[deformation]
preset = "heartbeat"
amplitude_m = 0.001

[[objects]]
kind = "instrument"
name = "grasper"
look = "metal"
motion = { jaw_open_deg = 30, entry_fraction = 0.0 }

[[objects]]
kind = "mesh"
file = "box.stl"
scale = 0.001
class = "clip"
id = 20
pose = { position = [0.0, 0.0, 0.045] }

[[tracked_frames]]
name = "lesion"
attached_to = "tissue"
pixel = [19.5, 14.5]

[[tracked_frames]]
name = "jaw_point"
attached_to = "grasper/jaw_upper"
position = [0.0, 0.0, 0.005]
"""

CONFIG_YAML = """
deformation: {preset: heartbeat, amplitude_m: 0.001}
objects:
  - {kind: instrument, name: grasper, look: metal, motion: {jaw_open_deg: 30, entry_fraction: 0.0}}
  - {kind: mesh, file: box.stl, scale: 0.001, class: clip, id: 20, pose: {position: [0.0, 0.0, 0.045]}}
tracked_frames:
  - {name: lesion, attached_to: tissue, pixel: [19.5, 14.5]}
  - {name: jaw_point, attached_to: grasper/jaw_upper, position: [0.0, 0.0, 0.005]}
"""


def test_toml_and_yaml_say_the_same(tmp_path):
    _box_file(tmp_path)
    (tmp_path / "a.toml").write_text(CONFIG_TOML)
    (tmp_path / "a.yaml").write_text(CONFIG_YAML)
    a, b = load_scene_config(tmp_path / "a.toml"), load_scene_config(tmp_path / "a.yaml")
    assert [s.instrument for s in a.instruments] == [s.instrument for s in b.instruments]
    assert a.instruments[0].motion == b.instruments[0].motion and a.instruments[0].motion.jaw_open_deg == 30
    assert a.meshes[0].file == b.meshes[0].file == (tmp_path / "box.stl").resolve()
    np.testing.assert_array_equal(a.meshes[0].pose, b.meshes[0].pose)
    assert a.deformation() == b.deformation() == Deformation.preset("heartbeat", amplitude_m=0.001)
    assert [(f.object, f.part) for f in a.tracked_frames] == [("tissue", None), ("grasper", "jaw_upper")]


@pytest.mark.parametrize("data, key", [
    ({"objects": [{"kind": "mesh", "file": "box.stl", "colour": [1, 0, 0]}]}, "objects[0].colour: unknown key"),
    ({"objects": [{"kind": "mesh", "file": "nope.obj"}]}, "objects[0].file: mesh file not found"),
    ({"objects": [{"kind": "mesh", "file": "box.stl", "pose": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                [0, 0, 0, 1]]}]}, "objects[0].pose: matrix"),
    ({"objects": [{"kind": "instrument", "id": 7}, {"kind": "mesh", "file": "box.stl", "id": 9}]},
     "objects[1].id: id 9 is already used by objects[0]"),
    ({"tracked_frames": [{"name": "a", "attached_to": "clamp", "position": [0, 0, 0]}]},
     "tracked_frames[0].attached_to: unknown object 'clamp'"),
    ({"objects": [{"kind": "drill"}]}, "objects[0].kind: kind must be one of"),
    ({"objects": [{"kind": "instrument", "motion": {"hover": -1}}]}, "objects[0].motion.hover: must be positive"),
    ({"objects": [{"kind": "instrument", "look": "gold"}]}, "objects[0].look: must be one of"),
    ({"deformation": {"amplitude_m": 0.001}}, "deformation.preset: overrides need a preset"),
    ({"objects": [{"kind": "mesh", "file": "box.stl", "pose": {"position": [0, 0, 0]},
                   "motion": {"path_file": "box.stl"}}]}, "objects[0].motion: give a pose or a motion"),
])
def test_configuration_errors_name_the_key(tmp_path, data, key):
    _box_file(tmp_path)
    with pytest.raises(ConfigError) as info:
        config = parse_scene_config(data, tmp_path)
        config.deformation()
    assert str(info.value).startswith(key), str(info.value)


def _scene(frames: int = 4) -> SceneDescription:
    rig = StereoRig.parallel(Intrinsics(64, 32, 40.0, 40.0, 31.5, 15.5), 0.005, clip_start=0.001, clip_end=2.0)
    return SceneDescription(rig, CameraPath(np.tile(np.eye(4), (frames, 1, 1)), fps=10.0), Light(),
                            [tissue_object("as_captured", texture=None)])


def test_objects_ids_files_and_tracked_frames(tmp_path):
    _box_file(tmp_path)
    (tmp_path / "a.toml").write_text(CONFIG_TOML)
    config = load_scene_config(tmp_path / "a.toml")
    plane = _grid_plane()
    desc = _scene()
    deformation = config.deformation(centre=(0.0, 0.0, PLANE_Z))
    desc.objects[0].parts[0].deformation = deformation
    tissue = Tissue(plane.vertices, plane.triangles, raycaster(plane.vertices, plane.triangles), CAPTURE.K)
    desc, record = add_objects(desc, tissue, config, tmp_path, seed=2)
    table = desc.object_table()
    # ids: tissue 1, the instrument's parts 2-5, the mesh its own 20, then the tracked frames in order
    assert {k: (v["name"], v["part"], v["class"]) for k, v in table["objects"].items()} == {
        "1": ("tissue", "surface", "tissue"), "2": ("grasper", "shaft", "instrument_shaft"),
        "3": ("grasper", "wrist", "instrument_wrist"), "4": ("grasper", "jaw_upper", "instrument_jaw"),
        "5": ("grasper", "jaw_lower", "instrument_jaw"), "20": ("box", "body", "clip")}
    assert table["tracked_frames"] == {"6": {"name": "tip", "attached_to": "grasper/wrist"},
                                       "7": {"name": "lesion", "attached_to": "tissue/surface"},
                                       "8": {"name": "jaw_point", "attached_to": "grasper/jaw_upper"}}
    assert record["instruments"][0]["ids"] == [2, 3, 4, 5] and record["meshes"][0]["id"] == 20
    # geometry files: each part in its own frame
    for _, part in desc.parts()[1:]:
        assert (tmp_path / part.geometry).is_file()
    box = read_ply(tmp_path / "objects" / "20.ply")
    np.testing.assert_allclose(np.ptp(box.vertices, axis=0), 0.004, rtol=1e-6)
    # the scene model round-trips through scene.json's dict
    again = SceneDescription.from_dict(json.loads(json.dumps(desc.to_dict())))
    for f in (0, 3):
        ids, poses = desc.tracked_poses(f)
        ids2, poses2 = again.tracked_poses(f)
        np.testing.assert_array_equal(ids, [1, 2, 3, 4, 5, 20, 7, 6, 8])  # parts, then frames by object
        np.testing.assert_array_equal(ids2, ids) and np.testing.assert_array_equal(poses2, poses)
    # the lesion: where the capture's ray through the pixel meets the plane, following the heartbeat
    ray = np.array([(19.5 - CAPTURE.cx) / CAPTURE.fx, (14.5 - CAPTURE.cy) / CAPTURE.fy, 1.0])
    anchor = desc.objects[0].tracked_frames[0].anchor
    rest = anchor.point()
    np.testing.assert_allclose(rest, ray * PLANE_Z, atol=1e-12)
    offset = desc.objects[0].tracked_frames[0].offset  # at rest: z along the surface normal, to the camera
    np.testing.assert_allclose(offset[:3, 2], [0, 0, -1], atol=1e-9)
    normals = rest_normals(plane.vertices, plane.triangles)
    for f in range(4):
        t = desc.time(f)
        moved = deformation.displace(plane.vertices, normals, t)  # the whole surface, independently
        expected = np.asarray(anchor.weights) @ moved[list(anchor.vertices)]
        ids, poses = desc.tracked_poses(f)
        np.testing.assert_allclose(poses[list(ids).index(7)][:3, 3], expected, atol=1e-12)
    # the frame on the jaw moves with the jaw
    jaw = desc.objects[1].part("jaw_upper")
    ids, poses = desc.tracked_poses(2)
    np.testing.assert_allclose(poses[list(ids).index(8)][:3, 3], (jaw.pose_at(2) @ [0, 0, 0.005, 1])[:3])


def test_scene_checks_objects_against_the_view_and_the_tissue(tmp_path):
    _box_file(tmp_path)
    plane = _grid_plane()
    tissue = Tissue(plane.vertices, plane.triangles, raycaster(plane.vertices, plane.triangles), CAPTURE.K)
    for data, message in (
        ({"objects": [{"kind": "mesh", "file": "box.stl", "scale": 0.001, "pose": {"position": [0.5, 0, 0.04]}}]},
         "objects[0]: 'box' never enters the view"),
        ({"objects": [{"kind": "mesh", "file": "box.stl", "scale": 0.001,
                       "motion": {"keyframes": [{"frame": 9, "position": [0, 0, 0.04]}]}}]},
         "objects[0].motion.keyframes: waypoint frames must lie in 0..3"),
        ({"tracked_frames": [{"name": "a", "attached_to": "tissue", "position": [0.0, 0.0, 0.08]}]},
         "tracked_frames[0].position: 30.0 mm from the tissue surface"),
    ):
        with pytest.raises(ConfigError) as info:
            add_objects(_scene(), tissue, parse_scene_config(data, tmp_path), tmp_path)
        assert str(info.value).startswith(message), str(info.value)


# ------------------------------------------------------------------------------------- through the CLI

@pytest.fixture(scope="module")
def mesh_folder(tmp_path_factory) -> Path:
    """A mesh folder (as 'rgbd2scene mesh' writes it) of a plane seen by a small capture camera."""
    folder = tmp_path_factory.mktemp("mesh_folder")
    write_ply(folder / "mesh.ply", _grid_plane())
    (folder / "scene.json").write_text(json.dumps({"capture": {"intrinsics": CAPTURE.to_dict()}}))
    _box_file(folder)
    return folder


@pytest.mark.parametrize("text, suffix, key", [
    ('[[objects]]\nkind = "mesh"\nfile = "box.stl"\ncolour = [1, 0, 0]\n', ".toml", "objects[0].colour: unknown key"),
    ('[[objects]]\nkind = "mesh"\nfile = "missing.obj"\n', ".toml", "objects[0].file: mesh file not found"),
    ("objects:\n  - {kind: mesh, file: box.stl, pose: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]}\n", ".yaml",
     "objects[0].pose: matrix must be a 4x4 matrix"),
    ("objects:\n  - {kind: mesh, file: box.stl, id: 4}\n  - {kind: mesh, file: box.stl, name: b, id: 4}\n", ".yaml",
     "objects[1].id: id 4 is already used by objects[0]"),
    ('[[objects]]\nkind = "mesh"\nfile = "box.stl"\nscale = 0.001\npose = { position = [0.3, 0.0, 0.04] }\n',
     ".toml", "objects[0]: 'box' never enters the view"),
    ("tracked_frames:\n  - {name: tip2, attached_to: forceps/jaw, position: [0, 0, 0]}\n", ".yaml",
     "tracked_frames[0].attached_to: unknown object 'forceps'"),
    ("objects: [kind: mesh\n", ".yaml", "not valid YAML (line 2"),
])
def test_bad_configurations_exit_2_with_one_line(mesh_folder, tmp_path, text, suffix, key):
    config = mesh_folder / f"bad{suffix}"
    config.write_text(text)
    result = subprocess.run([sys.executable, "-m", "rgbd2scene.cli", "scene", "--mesh-dir", str(mesh_folder),
                             "--scene-config", str(config), "--size", "64x32", "--frames", "3", "--path", "static",
                             "--standoff", "0.03", "-o", str(tmp_path / "scene")], capture_output=True, text=True)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {config}: {key}"), result.stderr
    assert not (tmp_path / "scene" / "scene.json").exists()


def test_scene_options_declare_the_flags():
    from rgbd2scene.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["scene", "--mesh-dir", "m", "--instrument", "--scene-config", "s.toml", "-o", "o"])
    assert args.instrument is True and args.scene_config == "s.toml"
    assert parser.parse_args(["scene", "-o", "o"]).instrument is False
