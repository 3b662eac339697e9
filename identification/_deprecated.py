"""Names that moved, kept at their old paths for one release."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable


def deprecated_aliases(module_name: str, moved: dict[str, str]) -> Callable[[str], object]:
    """A module-level `__getattr__` for `module_name`: each old name of `moved` (`{old: "new.dotted.path"}`)
    warns a `DeprecationWarning` naming its new path and returns the object there; other names raise
    `AttributeError`."""

    def __getattr__(name: str):
        if name not in moved:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        module, _, attribute = moved[name].rpartition(".")
        warnings.warn(f"{module_name}.{name} moved to {moved[name]}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(module), attribute)

    return __getattr__
