"""The nu-continuation of a batched sweep (`_continuation`, issue 6) with a stand-in solver whose
outcome depends only on whether it was started cold: order of solution, warm starts, the cold retry
of a failed warm member, and a member that fails both ways reported as failed."""

import jaxrobot as jr  # noqa: F401, I001  (x64 first)
import jax.numpy as jnp
import numpy as np

from jaxrobot import RESULTS
from jaxrobot._status import where
from planning._al_batch import _continuation
from planning.internal import OCPSolverResult

N, M = 3, 4
"""Nodes and history length of the stand-in problem."""
Y0 = jnp.zeros((N, 30))
DUAL = (jnp.zeros((N - 1, 24)), jnp.zeros((N, 30)))


def _stand_in(x, y, dual):
    """Converges to `Y0 + target` unless it `fails_warm` and was started warm, or `fails_always`;
    reports 9 iterations from a cold start, 1 from a warm one, and the start's first entry."""
    target, fails_warm, fails_always = x
    cold = jnp.all(y == Y0)
    failed = (fails_warm & ~cold) | fails_always
    z = lambda *shape: jnp.zeros(shape)  # noqa: E731
    return OCPSolverResult(y=Y0 + target, multipliers=dual[0] + target, bound_multipliers=dual[1],
                    status=where(failed, RESULTS.nonlinear_max_steps_reached, RESULTS.successful),
                    iterations=jnp.where(cold, 9, 1), inner_iterations=jnp.array(0), objective=y[0, 0],
                    violation=jnp.array(0.0), stationarity=jnp.array(0.0), history_objective=z(M),
                    history_violation=z(M), history_penalty=z(M), history_stationarity=z(M))


def _sweep(nu, fails_warm, fails_always):
    nu = jnp.asarray(nu)
    target = jnp.log10(nu) + 20.0  # distinct, nonzero solutions: a warm start is never Y0
    xs = [target, jnp.asarray(fails_warm), jnp.asarray(fails_always)]
    return _continuation(_stand_in, nu.size, nu, xs, Y0, DUAL, M), np.asarray(target)


def test_members_in_increasing_nu_warm_after_the_first():
    out, target = _sweep([1e-12, 1e-14, 1e-10, 1e-13], [False] * 4, [False] * 4)
    assert np.all(np.asarray(out.status == RESULTS.successful))
    np.testing.assert_array_equal(np.asarray(out.y[:, 0, 0]), target)  # caller's order
    # the smallest nu (caller's index 1) is cold, every other member warm
    np.testing.assert_array_equal(np.asarray(out.iterations), [1, 9, 1, 1])
    # second member (1e-13) starts from the first one's solution (one converged member: no secant)
    assert float(out.objective[3]) == target[1]


def test_failed_warm_member_is_retried_cold():
    out, target = _sweep([1e-14, 1e-13, 1e-12], [False, True, False], [False] * 3)
    assert np.all(np.asarray(out.status == RESULTS.successful))
    np.testing.assert_array_equal(np.asarray(out.y[:, 0, 0]), target)
    np.testing.assert_array_equal(np.asarray(out.iterations), [9, 9, 1])  # the retry is a cold solve
    assert float(out.objective[1]) == 0.0  # ... from Y0


def test_member_failing_cold_is_reported_and_the_next_starts_cold():
    out, _ = _sweep([1e-14, 1e-13, 1e-12], [False] * 3, [False, True, False])
    np.testing.assert_array_equal(jr.status_name(out.status),
                                  ["successful", "nonlinear_max_steps_reached", "successful"])
    # no converged predecessor after the failure: the third member is cold as well
    np.testing.assert_array_equal(np.asarray(out.iterations), [9, 9, 9])
