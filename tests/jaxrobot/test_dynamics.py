"""The rigid-body dynamics and statics of the robot model (thesis ch. 2): mass matrix, Coriolis, gravity,
inverse dynamics, static equilibrium."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import random_states

import jaxrobot as jr

ROBOT = jr.racer7()
TRUTH = jr.racer7(as_built=True)


def test_mass_matrix_is_symmetric_positive_definite():
    q, _, _ = random_states(200, seed=4)
    d = np.asarray(jr.mass_matrix(ROBOT, jnp.asarray(q)))
    np.testing.assert_allclose(d, np.swapaxes(d, -1, -2), atol=1e-13)
    assert np.linalg.eigvalsh(d).min() > 0


@pytest.mark.extended  # Christoffel symbols by nested autodiff compile for 17 s; pinocchio checks C qd in the suite
def test_coriolis_newton_euler_equals_christoffel_and_ddot_minus_2c_is_skew():
    q, qd, _ = (jnp.asarray(x) for x in random_states(50, seed=5))
    c = jr.coriolis_matrix(ROBOT, q, qd)
    h = jr.coriolis_vector(ROBOT, q, qd)
    scale = float(jnp.max(jnp.abs(h)))
    np.testing.assert_allclose(jnp.einsum("nij,nj->ni", c, qd), h, atol=1e-12 * scale)
    d_dot = jax.jvp(lambda q: jr.mass_matrix(ROBOT, q), (q,), (qd,))[1]
    n = d_dot - 2 * c
    assert float(jnp.max(jnp.abs(n + jnp.swapaxes(n, -1, -2)))) < 1e-12 * float(jnp.max(jnp.abs(n)))


def test_gravity_is_the_gradient_of_the_potential():
    def potential(q):  # V = -sum_i m_i gravity . c_i (eq. 2.19)
        frames = jr.link_frames(ROBOT, q)
        com = frames[:, :3, 3] + jnp.einsum("lij,lj->li", frames[:, :3, :3], ROBOT.com)
        return -jnp.sum(ROBOT.mass * (com @ ROBOT.gravity))

    q, _, _ = random_states(10, seed=6)
    for qi in jnp.asarray(q):
        np.testing.assert_allclose(jr.gravity_torque(ROBOT, qi), jax.grad(potential)(qi), atol=1e-11)


def test_inverse_dynamics_is_d_qdd_plus_c_qd_plus_g():
    q, qd, qdd = (jnp.asarray(x) for x in random_states(50, seed=7))
    ref = (jnp.einsum("nij,nj->ni", jr.mass_matrix(ROBOT, q), qdd) + jr.coriolis_vector(ROBOT, q, qd)
           + jr.gravity_torque(ROBOT, q))
    np.testing.assert_allclose(jr.inverse_dynamics(ROBOT, q, qd, qdd), ref, rtol=1e-12, atol=1e-10)


def test_static_equilibrium_holds_the_link_at_rest():
    q, _, _ = random_states(50, seed=8)
    q = jnp.asarray(q)
    theta = jr.static_equilibrium(ROBOT, q)
    x = jnp.concatenate([q, 0 * q, theta, 0 * q], -1)
    xd = jr.planning_dynamics(ROBOT, x, jnp.zeros(6))
    np.testing.assert_array_equal(xd[:, :6], 0.0)
    # Floor of float64: theta is resolved to eps |theta|, i.e. eps |theta| / u0 at the gear output,
    # which the stiffness turns into a torque and D^-1 into an acceleration. For |theta| ~ 250 rad
    # this floor reaches ~1e-8 rad/s^2 on the light wrist; at the 1e-9 of the issue where it allows.
    torque_floor = 4 * np.finfo(float).eps * jnp.abs(theta) / ROBOT.u0 * (ROBOT.k1 + 3 * ROBOT.k3 * 1e-4)
    d_inv = jnp.linalg.inv(jr.mass_matrix(ROBOT, q))
    bound = jnp.maximum(1e-9, jnp.einsum("nij,nj->ni", jnp.abs(d_inv), torque_floor))
    assert bool(jnp.all(jnp.abs(xd[:, 6:12]) <= bound)), "link acceleration at rest"
    assert float(jnp.median(jnp.abs(xd[:, 6:12]))) < 1e-10


def test_motor_torque_balances_the_reflected_elastic_torque_at_rest():
    q = jnp.asarray(random_states(5, seed=9)[0])
    theta = jr.static_equilibrium(ROBOT, q)
    tau_m = jr.motor_torque(ROBOT, q, theta, jnp.zeros_like(q))
    np.testing.assert_allclose(tau_m * jr.gear_ratio(ROBOT, jr.gear_output(ROBOT, theta)),
                               jr.gravity_torque(ROBOT, q), rtol=1e-10, atol=1e-9)


def test_planning_dynamics_shapes_and_batching_of_robots():
    fleet = jax.tree.map(lambda a, b: jnp.stack([a, b]), ROBOT, TRUTH)
    q = jnp.asarray(random_states(2, seed=10)[0])
    d = jr.mass_matrix(fleet, q)
    np.testing.assert_allclose(d[1], jr.mass_matrix(TRUTH, q[1]), rtol=1e-14)
    x = jnp.concatenate([q, q, 80 * q, q], -1)
    assert jr.planning_dynamics(fleet, x, jnp.ones((2, 6))).shape == (2, 24)


@pytest.mark.extended  # compiles frames, inverse dynamics and its gradient twice, looped and unrolled
def test_unrolled_link_loops_equal_the_loops(monkeypatch):
    """`UNROLL_LINKS` (the benchmark's variant) removes the loops over the links from the program and changes no
    number: frames, inverse dynamics and its reverse pass as with the loops, to round-off."""
    import jaxrobot._batch

    q, qd, qdd = (jnp.asarray(x) for x in random_states(20, seed=11))

    def evaluate():  # a new `jit` traces under the current setting
        fn = jax.jit(lambda q, qd, qdd: (jr.link_frames(TRUTH, q), jr.inverse_dynamics(TRUTH, q, qd, qdd),
                                         jax.grad(lambda q: jnp.sum(jr.inverse_dynamics(TRUTH, q, qd, qdd)))(q)))
        return "while" in fn.lower(q, qd, qdd).as_text(), fn(q, qd, qdd)

    looped, loops = evaluate()
    monkeypatch.setattr(jaxrobot._batch, "UNROLL_LINKS", True)
    still_looped, unrolled = evaluate()
    assert looped and not still_looped
    for a, b in zip(loops, unrolled, strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-13, atol=1e-12 * float(jnp.max(jnp.abs(a))))
