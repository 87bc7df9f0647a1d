"""Package names that load their submodule on first use (PEP 562), so that a command imports only what it runs.

A package's ``__init__`` lists its public names by submodule and sets ``__getattr__, __dir__ =
lazy_names(__name__, ...)``: ``from rgbd2scene.scene import SceneDescription`` still works, but
``rgbd2scene mesh``, which needs only ``rgbd2scene.scene.folder``, no longer imports (and, without cached
bytecode, compiles) the scene model, the camera paths, the contact sheet, the dataset reader or the Open3D
preview at every start.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from importlib import import_module


def lazy_names(package: str, submodule_of: dict[str, str]) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The module ``__getattr__`` and ``__dir__`` of ``package``.

    ``__getattr__``: ``name`` is looked up in ``package.<submodule_of[name]>``, imported then, and bound in the
    package (later accesses find it there, as after an eager import); any other name is an ``AttributeError``
    (which also lets ``from package import submodule`` import the submodule). A name must not be its
    submodule's name: importing that submodule elsewhere would rebind the package's attribute to the module.
    ``__dir__``: the package's own names and the lazy ones (tab completion sees them before their first use).
    """
    if clash := sorted(name for name, module in submodule_of.items() if name == module):
        raise ValueError(f"{package}: {clash} named as their own submodules")

    def __getattr__(name: str) -> object:
        if name not in submodule_of:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(f"{package}.{submodule_of[name]}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(submodule_of))

    return __getattr__, __dir__
