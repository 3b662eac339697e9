"""Deprecated: the names of `jaxrobot.checks` moved to `jaxrobot.internal`; the old names go in the next release."""

from ._deprecation import deprecated_aliases as _deprecated_aliases

__getattr__ = _deprecated_aliases(__name__, {name: f"jaxrobot.internal.{name}" for name in (
    "check_public",
    "checked",
    "deprecated_aliases",
    "require_elastic",
)})
