"""Deprecated: the names of `jaxrobot.linalg` moved to `jaxrobot.internal`; the old names go in the next release."""

from ._deprecation import deprecated_aliases as _deprecated_aliases

__getattr__ = _deprecated_aliases(__name__, {name: f"jaxrobot.internal.{name}" for name in (
    "cholesky",
    "cholesky_solve",
    "inverse_cholesky_factor",
    "map_matrices",
    "solve",
    "spd_solve",
)})
