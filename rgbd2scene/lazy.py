"""Package names that load their submodule on first use (PEP 562), so that a command imports only what it runs.

A package's ``__init__`` lists its public names by submodule and sets ``__getattr__ = lazy_names(__name__,
...)``: ``from rgbd2scene.scene import SceneDescription`` still works, but ``rgbd2scene mesh``, which needs only
``rgbd2scene.scene.folder``, no longer imports (and, without cached bytecode, compiles) the scene model, the
camera paths, the contact sheet, the dataset reader or the Open3D preview at every start.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from importlib import import_module


def lazy_names(package: str, submodule_of: dict[str, str]) -> Callable[[str], object]:
    """The module ``__getattr__`` of ``package``: ``name`` is looked up in ``package.<submodule_of[name]>``,
    imported then, and bound in the package (later accesses find it there); any other name is an
    ``AttributeError`` (which also lets ``from package import submodule`` import the submodule)."""

    def __getattr__(name: str) -> object:
        if name not in submodule_of:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(f"{package}.{submodule_of[name]}"), name)
        # Bound here, as an eager import would: importing the submodule bound the package's attribute of the
        # submodule's name to the submodule, which would hide a name it shares (rgbd2scene.pictures.preview)
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__
