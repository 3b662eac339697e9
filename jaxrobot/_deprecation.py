"""Deprecated aliases of public names that moved: the old path keeps working for one release, with a warning."""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Callable


def deprecated_aliases(module_name: str, moved: dict[str, str]) -> Callable[[str], object]:
    """A module-level `__getattr__` for `module_name` that returns the object at `moved[name]` (a dotted
    path "package.module.attr") for each old `name`, warning `DeprecationWarning` that names both paths.

    Also sets the module's `__dir__` (when it has none) to its public face: the names without a leading
    underscore that are not modules, the deprecated ones left out. Call it in the module's own body:
    `__getattr__ = deprecated_aliases(__name__, {...})`."""

    def __getattr__(name: str):
        if name not in moved:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        module, _, attr = moved[name].rpartition(".")
        warnings.warn(f"{module_name}.{name} moved to {moved[name]}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(module), attr)

    namespace = vars(sys.modules[module_name])

    def __dir__() -> list[str]:
        return public_names(namespace)

    namespace.setdefault("__dir__", __dir__)
    return __getattr__


def public_names(namespace: dict[str, object]) -> list[str]:
    """The public face of a module namespace: its names without a leading underscore, its submodules
    and the modules it imports left out, sorted."""
    return sorted(k for k, v in namespace.items() if not k.startswith("_") and not isinstance(v, type(sys)))


def renamed_argument(function: str, old: str, new: str, old_value, new_value):
    """The value of keyword `new` of `function` when callers may still pass it under its old name `old`
    (for one release, with a `DeprecationWarning` naming both); `ValueError` when both are given."""
    if old_value is None:
        return new_value
    if new_value is not None:
        raise ValueError(f"{function}: `{old}=` is the old name of `{new}=`; pass only `{new}=`")
    warnings.warn(f"{function}({old}=...) is now {function}({new}=...); the old name goes in the next release",
                  DeprecationWarning, stacklevel=3)
    return old_value
