"""The one place where this package uses a JAX internal, for want of a public API.

Written for jax 0.10.2 to 0.12.0.1 and tested on each version CI installs
(`tests/jaxrobot/test_jax_internals.py`). Every name here has a fallback, so that a JAX release that moves
the internal costs the documented loss and nothing else.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

try:  # public `jax.lax.convert_element_type` makes strongly typed arrays only
    from jax._src.lax.lax import _convert_element_type
except ImportError:  # a later JAX moved it: see `weakly_typed`
    _convert_element_type = None

try:  # jaxlib binds its LAPACK kernels to scipy's LAPACK when JAX lowers a call of one
    from jaxlib.lapack import prepare_lapack_call as _prepare_lapack_call
except ImportError:  # a later jaxlib moved it: see `initialize_lapack`
    _prepare_lapack_call = None

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


def initialize_lapack() -> None:
    """Bind jaxlib's CPU LAPACK kernels to their LAPACK routines, as JAX does when it lowers a call of one: a
    deserialized executable lowers nothing, and its first LAPACK call would jump to an unbound routine. Without the
    internal (a jaxlib that moved it), a small LAPACK call is lowered to the same end, in a tenth of a second more."""
    if _prepare_lapack_call is not None:
        _prepare_lapack_call("potrf_ffi", np.dtype(np.float64))
    else:
        jax.jit(jnp.linalg.cholesky).lower(jax.ShapeDtypeStruct((2, 2), jnp.float64))
