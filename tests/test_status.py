"""The project's one status vocabulary (`jaxrobot.RESULTS`, issue 18): names in code order, messages,
batches and `throw` (`RESULTS.error_if`) under `jit` and `vmap`."""

import jaxrobot as jr  # noqa: I001  (x64 first)
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import planning as pl
from jaxrobot._status import NAMES, check, where


def test_names_are_the_enumeration_in_code_order():
    assert len(NAMES) == len(jr.RESULTS) and len(set(NAMES)) == len(NAMES)
    for name in NAMES:
        assert jr.status_name(getattr(jr.RESULTS, name)) == name
    assert pl.RESULTS is jr.RESULTS
    # optimistix's own results promote to ours with their names kept
    assert jr.status_name(jr.RESULTS.promote(optx.RESULTS.nonlinear_max_steps_reached)) == "nonlinear_max_steps_reached"


def test_batched_status_names_and_messages():
    status = where(jnp.asarray([True, False, True]), jr.RESULTS.successful, jr.RESULTS.rank_deficient)
    assert jr.status_name(status).tolist() == ["successful", "rank_deficient", "successful"]
    messages = jr.status_message(status)
    assert messages[0] == "converged" and "rank deficient" in messages[1]
    assert jr.status_message(jr.RESULTS.inner_failed).startswith("The inner Gauss-Newton")


def test_throw_raises_the_message_under_jit_and_vmap():
    @eqx.filter_jit
    def solve(x, throw):
        status = jax.vmap(lambda v: jr.RESULTS.where(v > 0, jr.RESULTS.nonfinite, jr.RESULTS.successful))(x)
        return check(status, x, throw)

    np.testing.assert_array_equal(solve(jnp.asarray([-1.0, 1.0]), False), [-1.0, 1.0])
    np.testing.assert_array_equal(solve(jnp.asarray([-1.0, -2.0]), True), [-1.0, -2.0])
    with pytest.raises(Exception, match="Nonfinite"):
        solve(jnp.asarray([-1.0, 1.0]), True)
