"""The one place where this package uses a JAX internal, for want of a public API.

Written for jax 0.10.2 to 0.12.0.1 and tested on each version CI installs
(`tests/jaxrobot/test_jax_internals.py`). Every name here has a fallback, so that a JAX release that moves
the internal costs the documented loss and nothing else.
"""

from __future__ import annotations

import jax

try:  # public `jax.lax.convert_element_type` makes strongly typed arrays only
    from jax._src.lax.lax import _convert_element_type
except ImportError:  # a later JAX moved it: see `weakly_typed`
    _convert_element_type = None

JAX_VERSIONS_WRITTEN_FOR = ("0.10.2", "0.12.0.1")
"""The oldest and newest jax release this module was checked against."""


def weakly_typed(x: jax.Array) -> jax.Array:
    """`x` with JAX's weak type (the type of a Python scalar, which promotes to the other operand's
    dtype). A deserialized exported program forgets which of its outputs were weakly typed; this
    restores it. Without the internal (a JAX release that moved it), `x` is returned as it is:
    results are the same, but combine with float32 arrays as float64 ones do."""
    if _convert_element_type is None:
        return x
    return _convert_element_type(x, weak_type=True)
