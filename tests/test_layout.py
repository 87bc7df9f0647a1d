"""The house rules a reader relies on: bpy only in render/ (a lint rule), no state changed at import."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from itertools import pairwise
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _ruff(path: str, source: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--stdin-filename", path, "-"],
                          input=source, capture_output=True, text=True, cwd=REPO)


@pytest.mark.parametrize("source", ["import bpy\n", "from mathutils import Matrix\n", "import bpy.ops\n"])
def test_lint_rule_bans_blender_imports_outside_render(source):
    for path in ("rgbd2scene/anything.py", "benchmarks/bench_x.py", "tests/test_x.py"):
        result = _ruff(path, source)
        assert result.returncode != 0 and "TID251" in result.stdout, (path, result.stdout)
    assert "TID251" not in _ruff("render/anything.py", source).stdout


def test_importing_the_package_changes_no_process_state():
    """Importing every module of the numpy core leaves the umask and the environment as they were (the
    third-party libraries, some of which set variables of their own, are imported first: threadpoolctl sets
    KMP_DUPLICATE_LIB_OK). The child gets an environment without that variable, so that the result does not
    depend on which earlier test of this process loaded threadpoolctl."""
    code = ("import os, pkgutil, importlib, rgbd2scene, cv2, open3d, scipy, skimage, pymeshlab, OpenEXR\n"
            "import threadpoolctl\n"
            "os.umask(0o027); env = dict(os.environ)\n"
            "for m in pkgutil.walk_packages(rgbd2scene.__path__, 'rgbd2scene.'):\n"
            "    importlib.import_module(m.name)\n"
            "assert os.umask(0o027) == 0o027, 'umask changed'\n"
            "changed = sorted(k for k in set(env) | set(os.environ) if env.get(k) != os.environ.get(k))\n"
            "assert not changed, changed\n"
            "import sys; assert 'bpy' not in sys.modules, 'the numpy core imported bpy'\n")
    env = {k: v for k, v in os.environ.items() if k != "KMP_DUPLICATE_LIB_OK"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, env=env)
    assert result.returncode == 0, result.stderr[-2000:]


def _package_imports() -> dict[str, dict[str, str]]:
    """Who imports whom among rgbd2scene's top-level units (a subpackage or a top-level module): every import
    statement of every module, function-level and relative ones included, as {importer: {imported: where}}."""
    root = REPO / "rgbd2scene"
    graph: dict[str, dict[str, str]] = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(REPO).with_suffix("").parts
        package, unit = parts[:-1], parts[1]  # a relative import counts from the module's package
        if unit == "__init__":  # rgbd2scene/__init__.py: the package itself, no unit
            continue
        edges = graph.setdefault(unit, {})
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = ".".join(package[: len(package) - node.level + 1]) if node.level else ""
                module = ".".join(x for x in (base, node.module) if x)
                names = [module] + [f"{module}.{alias.name}" for alias in node.names]
            else:
                continue
            for name in names:
                target = name.split(".")
                if target[0] == "rgbd2scene" and len(target) > 1 and target[1] != unit and (
                        (root / target[1]).is_dir() or (root / f"{target[1]}.py").is_file()):
                    edges.setdefault(target[1], f"{path.relative_to(REPO)}:{node.lineno}")
    return graph


def _cycle(graph: dict[str, dict[str, str]]) -> list[str] | None:
    """One import cycle of the graph as [a, b, ..., a], or None (depth-first search)."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(unit: str) -> list[str] | None:
        state[unit] = 1
        path.append(unit)
        for dep in sorted(graph.get(unit, {})):
            if state.get(dep) == 1:
                return path[path.index(dep):] + [dep]
            if dep not in state and (found := visit(dep)):
                return found
        path.pop()
        state[unit] = 2
        return None

    for unit in sorted(graph):
        if unit not in state and (found := visit(unit)):
            return found
    return None


def test_cycle_search_finds_a_planted_cycle():
    assert _cycle({"a": {"b": ""}, "b": {"c": ""}, "c": {"a": ""}, "d": {"a": ""}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b": ""}, "b": {"c": ""}, "d": {"a": "", "c": ""}}) is None


def test_subpackages_import_each_other_without_a_cycle():
    """The subpackages form layers (geometry under capture, files, reconstruction, scene and ground truth; the
    stages, batch, cli and api on top): no chain of imports, lazy ones included, leads back to its start."""
    graph = _package_imports()
    # The parser sees the imports a reader sees (else an empty graph would pass).
    assert {"geometry", "errors"} <= set(graph["files"]) and "geometry" in graph["capture"], graph["files"]
    cycle = _cycle(graph)
    assert cycle is None, " -> ".join(f"{a} ({graph[a][b]})" for a, b in pairwise(cycle)) + f" -> {cycle[-1]}"


def test_geometry_imports_only_the_conventions():
    """The shared geometry (camera model, mesh, ray caster) sits below every stage: it may use the conventions,
    the errors and the lazy package names (which import nothing of the package), nothing else."""
    assert set(_package_imports()["geometry"]) <= {"conventions", "errors", "lazy"}


#: What the start of ``rgbd2scene mesh`` imports: the capture and mesh stages and the command line's parser.
MESH_START = ("import sys, rgbd2scene.stages.capture, rgbd2scene.stages.mesh, rgbd2scene.cli as cli\n"
              "cli.build_parser('mesh')\n")


def _run_fresh(code: str) -> None:
    """Run ``code`` in a fresh interpreter (what it imports is the code's own); fail with its error output."""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr[-2000:]


def test_a_stage_loads_without_the_others_and_the_package_names_all_resolve():
    """``rgbd2scene mesh`` imports the capture and mesh stages only (the scene, render and Blender stages cost
    a few tenths of a second at every start); ``rgbd2scene.stages.X`` still gives every documented name."""
    code = (MESH_START +
            "loaded = sorted(m for m in sys.modules if m.startswith('rgbd2scene.stages.'))\n"
            "assert loaded == ['rgbd2scene.stages.capture', 'rgbd2scene.stages.mesh'], loaded\n"
            "import rgbd2scene.stages as stages\n"
            "for name in stages.__all__:\n"
            "    assert getattr(stages, name).__module__.startswith('rgbd2scene.'), name\n"
            "from rgbd2scene.stages import RenderOptions, build_scene_folder\n"
            "assert not hasattr(stages, 'no_such_name')\n")
    _run_fresh(code)


def test_the_mesh_command_loads_no_scene_model_paths_or_dataset_and_package_names_resolve():
    """``rgbd2scene mesh`` needs only ``scene.folder`` and the overview of the pictures: the scene model, the
    camera paths, the contact sheet and the dataset reader are not imported at its start (nor compiled, where
    no bytecode is cached); every name the scene, geometry and pictures packages list still resolves."""
    code = (MESH_START +
            "import rgbd2scene.pictures.overview\n"
            "loaded = sorted(m for m in sys.modules if m.startswith(('rgbd2scene.scene.', 'rgbd2scene.dataset',\n"
            "                                                       'rgbd2scene.pictures.')))\n"
            "assert loaded == ['rgbd2scene.pictures.overview', 'rgbd2scene.scene.folder'], loaded\n"
            "import rgbd2scene.geometry, rgbd2scene.pictures, rgbd2scene.scene\n"
            "for package in (rgbd2scene.geometry, rgbd2scene.pictures, rgbd2scene.scene):\n"
            "    for name in package.__all__:\n"
            "        assert getattr(package, name) is not None, name\n"
            "    assert not hasattr(package, 'no_such_name')\n"
            "from rgbd2scene.scene import SceneDescription, folder\n")
    _run_fresh(code)


def test_a_single_frame_mesh_loads_no_fusion_or_trajectory():
    """Fusion (its ray caster, SciPy's graph routines) and trajectory files serve several frames only: the capture
    and mesh stages import them when a capture has several frames, not at the start of every ``rgbd2scene mesh``
    (25 ms of imports where no bytecode is cached); the software versions (importlib.metadata) are looked up on a
    worker thread during the reconstruction."""
    code = (MESH_START +
            "loaded = {'rgbd2scene.reconstruct.fusion', 'rgbd2scene.capture.trajectory',\n"
            "          'rgbd2scene.geometry.raycast', 'scipy.sparse.csgraph',\n"
            "          'rgbd2scene.versions'} & set(sys.modules)\n"
            "assert not loaded, loaded\n")
    _run_fresh(code)


def test_a_lazy_package_name_is_its_submodule_object_at_every_access():
    """A package name is the object its submodule defines, at the first access and at every later one, also where
    its submodule is imported directly (``rgbd2scene.pictures.preview``; a name that was its submodule's would
    then be the module), and ``dir()`` lists the names before their first use."""
    code = ("import types\n"
            "import rgbd2scene.geometry, rgbd2scene.pictures, rgbd2scene.scene, rgbd2scene.stages\n"
            "for package in (rgbd2scene.geometry, rgbd2scene.pictures, rgbd2scene.scene, rgbd2scene.stages):\n"
            "    assert set(package.__all__) <= set(dir(package)), package\n"
            "    for name in package.__all__:\n"
            "        first, second = getattr(package, name), getattr(package, name)\n"
            "        assert first is second and not isinstance(first, types.ModuleType), (name, first, second)\n"
            "from rgbd2scene.pictures import preview\n"
            "assert callable(preview), preview\n"
            "import rgbd2scene.pictures.mesh_preview\n"
            "assert rgbd2scene.pictures.preview is preview\n")
    _run_fresh(code)
