"""The flat inverse of the planning model (docs/model.md (B.4); not in the thesis).

The link angle is a flat output of eq. 4.1: for a smooth `q_d(t)`,
`phi = q_d + kappa^{-1}(D q̈_d + C q̇_d + g)`, `theta = Xi(phi)`, `u = θ̈`; the robot's link loads
(`jaxrobot.effects.LinkLoad`, functions of `q_d` and `q̇_d`) add to the bracket. It tracks exactly in
continuous time, ignores limits and the boundary conditions on `u`; it is the baseline and
the warm start of the optimal control problem.

With a joint torque besides the spring (`jaxrobot.effects.JointTorque`, a function of the deflection's rate,
docs/model.md (2.23c)) the deflection `x = phi - q_d` is no longer algebraic: the effect integrates it
(`JointTorque.flat_deflection`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._dynamics import holding_motor_angle, inverse_dynamics
from ._gear import motor_angle
from ._robot import Robot
from .effects._registry import terms


def _derivative(fn: Callable) -> Callable:
    return lambda t: jax.jvp(fn, (t,), (jnp.ones_like(t),))[1]


def flat_inverse(
    robot: Robot, q_d: Callable[[Float[Array, ""]], Float[Array, " n"]], t: Float[Array, " N"]
) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
    """Motor angles, rates and accelerations `(theta, thetad, thetadd)` at times `t` that make
    the elastic model follow `q_d` exactly (cw gear set, as the planning model).

    **Arguments:** `q_d` maps a scalar time [s] to link angles (n,) and must be four times
    differentiable (derivatives are taken by nested `jax.jvp`); `t` (N,) sample times [s] (uniform where the robot
    has a joint torque besides the spring, whose deflection is integrated from rest at `t[0]`: module docstring).
    """
    t = jnp.asarray(t, float)
    effects = terms(robot)

    def torque(s):
        q, qd, qdd = q_d(s), _derivative(q_d)(s), _derivative(_derivative(q_d))(s)
        tau = inverse_dynamics(robot, q, qd, qdd)
        for load in effects.link_loads:
            tau = tau + load.torque(robot, q, qd)
        return tau

    joint = effects.joint_torques
    if len(joint) > 1:
        raise ValueError(f"flat_inverse: expected at most one joint torque besides the spring, found "
                         f"{[e.name for e in joint]}")
    if not joint:
        def theta(s):
            return holding_motor_angle(robot, q_d(s), torque(s))

        def at(s):
            return theta(s), _derivative(theta)(s), _derivative(_derivative(theta))(s)

        return jax.vmap(at)(t)
    x, xd, xdd = joint[0].flat_deflection(robot, torque, t)
    phi = jax.vmap(lambda s: jnp.stack([q_d(s), _derivative(q_d)(s), _derivative(_derivative(q_d))(s)]))(t)
    phi = phi + jnp.stack([x, xd, xdd], 1)  # (N, 3, n): phi and its two rates

    def along(p):
        g = lambda s: motor_angle(robot, p[0] + s * p[1] + 0.5 * s**2 * p[2])  # noqa: E731
        value, first = jax.jvp(g, (0.0,), (1.0,))
        return value, first, jax.jvp(_derivative(g), (0.0,), (1.0,))[1]

    return jax.vmap(along)(phi)
