"""The flat inverse of the planning model (docs/model.md (B.4); not in the thesis).

The link angle is a flat output of eq. 4.1: for a smooth `q_d(t)`,
`phi = q_d + kappa^{-1}(D q̈_d + C q̇_d + g)`, `theta = Xi(phi)`, `u = θ̈`. It tracks exactly in
continuous time, ignores limits and the boundary conditions on `u`; it is the baseline and
the warm start of the optimal control problem.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._dynamics import inverse_dynamics
from ._elasticity import elastic_deflection
from ._gear import motor_angle
from ._robot import Robot


def _derivative(fn: Callable) -> Callable:
    return lambda t: jax.jvp(fn, (t,), (jnp.ones_like(t),))[1]


def flat_inverse(
    robot: Robot, q_d: Callable[[Float[Array, ""]], Float[Array, " n"]], t: Float[Array, " N"]
) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
    """Motor angles, rates and accelerations `(theta, thetad, thetadd)` at times `t` that make
    the elastic model follow `q_d` exactly (cw gear set, as the planning model).

    **Arguments:** `q_d` maps a scalar time [s] to link angles (n,) and must be four times
    differentiable (derivatives are taken by nested `jax.jvp`); `t` (N,) sample times [s].
    """

    def theta(s):
        q, qd, qdd = q_d(s), _derivative(q_d)(s), _derivative(_derivative(q_d))(s)
        return motor_angle(robot, q + elastic_deflection(robot, inverse_dynamics(robot, q, qd, qdd)))

    def at(s):
        return theta(s), _derivative(theta)(s), _derivative(_derivative(theta))(s)

    return jax.vmap(at)(jnp.asarray(t, float))
