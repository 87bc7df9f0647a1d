"""Package names that load their submodule on first use (PEP 562), so that a command imports only what it runs.

A package's ``__init__`` lists its public names by submodule and sets ``__getattr__ = lazy_names(__name__,
...)``: ``from rgbd2scene.scene import SceneDescription`` still works, but ``rgbd2scene mesh``, which needs only
``rgbd2scene.scene.folder``, no longer imports (and, without cached bytecode, compiles) the scene model, the
camera paths, the contact sheet, the dataset reader or the ray caster at every start.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module


def lazy_names(package: str, submodule_of: dict[str, str]) -> Callable[[str], object]:
    """The module ``__getattr__`` of ``package``: ``name`` is looked up in ``package.<submodule_of[name]>``,
    imported then; any other name is an ``AttributeError`` (which also lets ``from package import submodule``
    import the submodule)."""

    def __getattr__(name: str) -> object:
        if name not in submodule_of:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(f"{package}.{submodule_of[name]}"), name)

    return __getattr__
