"""The JAX internal behind `jaxrobot._jax_internals` is where it was when the module was written
(jax 0.10.2 to 0.12.0.1): a JAX release that moves it fails here by name, not somewhere downstream."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxrobot import _jax_internals


def test_the_internal_exists_on_this_jax():
    assert _jax_internals._convert_element_type is not None, (
        f"jax {jax.__version__}: jax._src.lax.lax._convert_element_type is gone (module written for jax "
        f"{' to '.join(_jax_internals.JAX_VERSIONS_WRITTEN_FOR)}); find its public successor")


def test_weakly_typed_restores_the_weak_type_and_keeps_the_values():
    x = jnp.array([1.5, -2.0])  # strongly typed float64
    out = jax.jit(_jax_internals.weakly_typed)(x)
    assert not x.weak_type and out.weak_type
    np.testing.assert_array_equal(np.asarray(out), np.asarray(x))
    # a weak float64 promotes to the other operand's dtype, as a Python float does
    assert (out + jnp.ones(2, jnp.float32)).dtype == jnp.float32
    assert (x + jnp.ones(2, jnp.float32)).dtype == jnp.float64


def test_weakly_typed_falls_back_to_the_input(monkeypatch):
    monkeypatch.setattr(_jax_internals, "_convert_element_type", None)
    x = jnp.array([1.5, -2.0])
    assert _jax_internals.weakly_typed(x) is x
