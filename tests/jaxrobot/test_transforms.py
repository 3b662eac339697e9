"""`jit`, `vmap` (1000 states) and `grad` through every public numeric function of jaxrobot."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import random_states

import jaxrobot as jr

ROBOT = jr.racer7(as_built=True)
Q, QD, QDD = (jnp.asarray(x) for x in random_states(1000, seed=11))
THETA = Q * ROBOT.u0
X = jnp.concatenate([Q, QD, jr.static_equilibrium(ROBOT, Q), QD * ROBOT.u0], -1)

# name -> (function of (robot, state), the batched state)
FUNCTIONS = {
    "forward_kinematics": (jr.forward_kinematics, Q),
    "tool_pose": (jr.tool_pose, Q),
    "link_frames": (jr.link_frames, Q),
    "point_position": (lambda r, q: jr.point_position(r, q, jnp.array([0.05, 0.02, 0.06])), Q),
    "geometric_jacobian": (jr.geometric_jacobian, Q),
    "analytic_jacobian": (jr.analytic_jacobian, Q),
    "gear_ratio": (lambda r, p: jr.gear_ratio(r, p, p > 0), Q),
    "motor_angle": (lambda r, p: jr.motor_angle(r, p, p > 0), Q),
    "gear_output": (lambda r, t: jr.gear_output(r, t, t > 0), THETA),
    "elastic_torque": (lambda r, x: jr.elastic_torque(r, 1e-3 * x), Q),
    "elastic_deflection": (lambda r, t: jr.elastic_deflection(r, 100 * t), Q),
    "mass_matrix": (jr.mass_matrix, Q),
    "coriolis_vector": (lambda r, q: jr.coriolis_vector(r, q, QD[0]), Q),
    "coriolis_matrix": (lambda r, q: jr.coriolis_matrix(r, q, QD[0]), Q),
    "gravity_torque": (jr.gravity_torque, Q),
    "inverse_dynamics": (lambda r, q: jr.inverse_dynamics(r, q, QD[0], QDD[0]), Q),
    "link_acceleration": (lambda r, q: jr.link_acceleration(r, q, QD[0], q + 1e-3), Q),
    "motor_torque": (lambda r, t: jr.motor_torque(r, jr.gear_output(r, t) - 1e-4, t, QDD[0]), THETA),
    "planning_dynamics": (lambda r, x: jr.planning_dynamics(r, x, QDD[0]), X),
    "planning_dynamics_damped": (lambda r, x: jr.planning_dynamics(
        dataclasses.replace(r, damping=2e-3 * jnp.sqrt(r.k1), motor_lag=jnp.full(6, 3e-3)), x, QDD[0]), X),
    "static_equilibrium": (jr.static_equilibrium, Q),
}


ACCELERATIONS = {"link_acceleration", "planning_dynamics", "planning_dynamics_damped"}


# the Coriolis matrix, the link acceleration and the planning dynamics, damped or not (about 30 s each to compile
# their second derivatives), in CI's extended step; in the suite `planning_dynamics` is batched over robots
# (test_model) and jitted and differentiated inside every OCP solve
SLOW_TRANSFORMS = {"coriolis_matrix", "link_acceleration", "planning_dynamics", "planning_dynamics_damped"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.extended) if n in SLOW_TRANSFORMS else n
                                  for n in FUNCTIONS])
def test_jit_vmap_grad(name):
    fn, states = FUNCTIONS[name]
    batched, broadcast = jax.jit(lambda r, s: (jax.vmap(fn, in_axes=(None, 0))(r, s), fn(r, s)))(ROBOT, states)
    assert batched.shape[0] == 1000 and bool(jnp.all(jnp.isfinite(batched)))
    # accelerations solve D qdd = kappa(phi - q) - g - C qd: phi = Xi^-1(theta) is resolved to
    # eps |theta| / u0 ~ 1e-15 rad, i.e. 2e-11 N m through k1, which the wrist's ~3e-3 kg m^2 turns
    # into ~1e-8 rad/s^2; vmap and batch axes round differently within that
    atol = 1e-8 if name in ACCELERATIONS else 1e-12
    np.testing.assert_allclose(batched, broadcast, rtol=1e-12, atol=atol, err_msg=f"{name}: vmap vs batch axes")
    # grad of a random linear functional w.r.t. the state and the robot, vs central differences
    rng = np.random.default_rng(12)
    x0 = states[3]
    direction = jnp.asarray(rng.normal(size=x0.shape))
    weights = jnp.asarray(rng.normal(size=batched.shape[1:]))
    scalar = lambda r, x: jnp.sum(weights * fn(r, x))  # noqa: E731
    h = 1e-6

    @jax.jit
    def check(r, x):
        g_robot, g_state = jax.grad(scalar, argnums=(0, 1))(r, x)
        fd = (scalar(r, x + h * direction) - scalar(r, x - h * direction)) / (2 * h)
        return g_robot, g_state @ direction, fd

    g_robot, g_dir, fd = check(ROBOT, x0)
    np.testing.assert_allclose(g_dir, fd, rtol=1e-5, atol=1e-6 * float(jnp.abs(fd)) + 1e-9,
                               err_msg=f"{name}: grad vs differences")
    finite = all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in jax.tree.leaves(g_robot))
    assert finite, f"{name}: grad wrt robot"
