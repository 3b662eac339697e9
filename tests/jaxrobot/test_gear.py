"""The gear: the motor-to-link map Xi with its ripple, its inverse and its derivatives (thesis 2.3)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import jaxrobot as jr

ROBOT = jr.racer7()
TRUTH = jr.racer7(as_built=True)


@pytest.mark.parametrize("ccw", [False, True], ids=["cw", "ccw"])
def test_gear_inverse_is_exact_over_the_joint_ranges(ccw):
    lo = np.asarray(ROBOT.q_min) * np.asarray(ROBOT.u0)
    hi = np.asarray(ROBOT.q_max) * np.asarray(ROBOT.u0)
    theta = jnp.asarray(np.linspace(lo, hi, 20001))
    phi = jr.gear_output(ROBOT, theta, ccw)
    assert float(jnp.max(jnp.abs(jr.motor_angle(ROBOT, phi, ccw) - theta))) < 1e-12


@pytest.mark.parametrize("ccw", [False, True], ids=["cw", "ccw"])
def test_gear_inverse_on_the_rippled_joints_only(ccw):
    """`rippled=(0, 1, 2)` (the Racer-7's rippled gears; the wrist has none): Xi of the result is theta
    to 1e-12 rad on every joint, the wrist is exactly theta / u0, and derivatives are 1/u(phi); also
    for a fleet of robots (fields (R, 1, ...)) against poses (R, K, 6)."""
    assert np.all(np.asarray(ROBOT.cw.orders)[3:] == 0) and np.all(np.asarray(ROBOT.ccw.orders)[3:] == 0)
    rng = np.random.default_rng(11)
    theta = jnp.asarray(rng.uniform(ROBOT.q_min, ROBOT.q_max, (4, 7, 6)) * np.asarray(ROBOT.u0))
    fleet = jax.tree.map(lambda x: jnp.stack([x, x * (1 + 1e-4 * isinstance(x, jax.Array))] * 2)[:, None], TRUTH)
    for robot in (ROBOT, TRUTH, fleet):
        phi = jr.gear_output(robot, theta, ccw, rippled=(0, 1, 2))
        assert float(jnp.max(jnp.abs(jr.motor_angle(robot, phi, ccw) - theta))) < 1e-12
        np.testing.assert_array_equal(phi[..., 3:], theta[..., 3:] / jnp.broadcast_to(robot.u0, theta.shape)[..., 3:])
    dphi = jax.vmap(lambda t: jnp.diag(jax.jacfwd(lambda s: jr.gear_output(ROBOT, s, ccw, (0, 1, 2)))(t)))(theta[0])
    np.testing.assert_allclose(dphi, 1 / jr.gear_ratio(ROBOT, jr.gear_output(ROBOT, theta[0], ccw), ccw), rtol=1e-12)
    np.testing.assert_allclose(jr.gear_output(ROBOT, theta, ccw, rippled=()), theta / ROBOT.u0, rtol=1e-15)


def test_gear_ratio_is_the_derivative_of_xi_and_xi_of_zero_is_zero():
    phi = jnp.asarray(np.random.default_rng(3).uniform(-2, 2, (50, 6)))
    for ccw in (False, True):
        du = jax.vmap(lambda p: jnp.diag(jax.jacfwd(lambda x: jr.motor_angle(ROBOT, x, ccw))(p)))(phi)
        np.testing.assert_allclose(du, jr.gear_ratio(ROBOT, phi, ccw), rtol=1e-13)
        np.testing.assert_array_equal(jr.motor_angle(ROBOT, jnp.zeros(6), ccw), np.zeros(6))
    # the relative ripple of joint 1 (cw) has the rms printed in racer7.toml: 3.107e-3
    p = jnp.linspace(0, 2 * jnp.pi, 200001)[:, None] * jnp.ones(6)
    ripple = jr.gear_ratio(ROBOT, p)[:, 0] / ROBOT.u0[0] - 1.0
    assert abs(float(jnp.sqrt(jnp.mean(ripple**2))) - 3.107e-3) < 1e-6


def test_gear_inverse_derivatives_follow_the_implicit_function():
    theta = jnp.array([10.0, -20.0, 30.0, 5.0, -7.0, 3.0])
    phi = jr.gear_output(ROBOT, theta)
    u = jr.gear_ratio(ROBOT, phi)
    np.testing.assert_allclose(jnp.diag(jax.jacfwd(lambda t: jr.gear_output(ROBOT, t))(theta)), 1 / u, rtol=1e-12)
    # second derivative: d2phi/dtheta2 = -u'(phi) / u^3
    du = jnp.diag(jax.jacfwd(lambda p: jr.gear_ratio(ROBOT, p))(phi))
    d2 = jnp.diag(jax.jacfwd(lambda t: jnp.diag(jax.jacfwd(lambda s: jr.gear_output(ROBOT, s))(t)))(theta))
    np.testing.assert_allclose(d2, -du / u**3, rtol=1e-9, atol=1e-20)


def test_gear_sincos_matches_numpy_and_differentiates_exactly():
    # the shared-reduction sin/cos of the gear harmonics (jaxrobot._gear._sincos) over |n phi| <= 2e3,
    # including the quadrant boundaries k pi/4; numpy's libm is correctly rounded to ~0.5 ulp
    from jaxrobot._gear import _sincos

    x = np.concatenate([np.random.default_rng(19).uniform(-2e3, 2e3, 20000), np.arange(-2544, 2545) * np.pi / 4])
    s, c = _sincos(jnp.asarray(x))
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=2.3e-16, err_msg="sin")
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=2.3e-16, err_msg="cos")
    ds, dc = jax.vmap(jax.grad(lambda t: _sincos(t)[0]))(jnp.asarray(x[:100])), \
        jax.vmap(jax.grad(lambda t: _sincos(t)[1]))(jnp.asarray(x[:100]))
    np.testing.assert_array_equal(ds, c[:100])
    np.testing.assert_array_equal(dc, -s[:100])


_motor_angle = jax.jit(jr.motor_angle, static_argnames="ccw")
_gear_output = jax.jit(jr.gear_output, static_argnames="ccw")
GEAR_AXIOMS = settings(max_examples=60, deadline=None, derandomize=True, database=None)
fractions = arrays(np.float64, 6, elements=st.floats(0.0, 1.0, allow_nan=False))
"""A point of the joint ranges as the fraction of the way from each lower to each upper limit."""


@GEAR_AXIOMS
@given(fractions, st.booleans(), st.booleans())
def test_gear_inverse_axioms(fraction, ccw, as_built):
    """For link angles `phi` anywhere in the joint ranges (drawn by hypothesis, derandomized), either flank
    and the nominal or the as-built gears: `gear_output(motor_angle(phi)) = phi` and
    `motor_angle(gear_output(theta)) = theta` (Newton to float64: ~eps |theta| with |theta| up to ~500 rad,
    the bound of the ranges test above), and `motor_angle` keeps the order of the angles (u(phi) > 0)."""
    robot = TRUTH if as_built else ROBOT
    phi = np.asarray(robot.q_min) + fraction * (np.asarray(robot.q_max) - np.asarray(robot.q_min))
    theta = _motor_angle(robot, jnp.asarray(phi), ccw)
    np.testing.assert_allclose(_gear_output(robot, theta, ccw), phi, rtol=0, atol=1e-13)
    np.testing.assert_allclose(_motor_angle(robot, _gear_output(robot, theta, ccw), ccw), theta, rtol=0, atol=1e-12)
    step = _motor_angle(robot, jnp.asarray(phi) + 1e-3, ccw) - theta
    assert np.all(np.asarray(step) > 0)

