"""Deprecated aliases of public names that moved: the old path keeps working for one release, with a warning."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable


def deprecated_aliases(module_name: str, moved: dict[str, str]) -> Callable[[str], object]:
    """A module-level `__getattr__` for `module_name` that returns the object at `moved[name]` (a dotted
    path "package.module.attr") for each old `name`, warning `DeprecationWarning` that names both paths."""

    def __getattr__(name: str):
        if name not in moved:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        module, _, attr = moved[name].rpartition(".")
        warnings.warn(f"{module_name}.{name} moved to {moved[name]}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(module), attr)

    return __getattr__
