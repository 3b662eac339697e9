"""The flat inverse of the planning model (docs/model.md (B.4); not in the thesis).

The link angle is a flat output of eq. 4.1: for a smooth `q_d(t)`,
`phi = q_d + kappa^{-1}(D q̈_d + C q̇_d + g)`, `theta = Xi(phi)`, `u = θ̈`; the robot's link loads
(`jaxrobot.effects.LinkLoad`: link-side friction, a function of `q̇_d`) add to the bracket. It tracks exactly in
continuous time, ignores limits and the boundary conditions on `u`; it is the baseline and
the warm start of the optimal control problem.

With joint damping `d` (docs/model.md (2.23c)) the deflection `x = phi - q_d` is no longer algebraic:
`d xd + kappa(x) = tau(t)`, `tau = D q̈_d + C q̇_d + g`, a stable first-order equation per joint (time constant
`d / kappa'`), integrated from rest (`x = kappa^{-1}(tau(0))`) by the two-point Hermite-Obreschkoff rule of
order 4 (A-stable: `d / k` may be far below the step) on `DAMPED_SUBSTEPS` steps per sample, with Newton on each
step; `xd` and `xdd` follow from the equation. Undamped joints (`d = 0`) keep `x = kappa^{-1}(tau)`.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._dynamics import inverse_dynamics
from ._elasticity import elastic_deflection, elastic_stiffness, elastic_torque
from ._gear import motor_angle
from ._robot import Robot
from .effects import link_loads

DAMPED_SUBSTEPS = 10
"""Steps per sample of the damped deflection (module docstring): at 0.1 ms the rule's error, ~`h^4` times the
fifth derivative of the deflection, is below 1e-12 rad for the reference tasks."""
DAMPED_NEWTON_STEPS = 3
"""Newton steps per step of the damped deflection, from the explicit second-order Taylor step (the equation is
linear but for the cubic spring term)."""


def _derivative(fn: Callable) -> Callable:
    return lambda t: jax.jvp(fn, (t,), (jnp.ones_like(t),))[1]


def flat_inverse(
    robot: Robot, q_d: Callable[[Float[Array, ""]], Float[Array, " n"]], t: Float[Array, " N"]
) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
    """Motor angles, rates and accelerations `(theta, thetad, thetadd)` at times `t` that make
    the elastic model follow `q_d` exactly (cw gear set, as the planning model).

    **Arguments:** `q_d` maps a scalar time [s] to link angles (n,) and must be four times
    differentiable (derivatives are taken by nested `jax.jvp`); `t` (N,) sample times [s] (uniform where the robot
    has joint damping, whose deflection is integrated from rest at `t[0]`: module docstring).
    """
    t = jnp.asarray(t, float)

    def torque(s):
        q, qd, qdd = q_d(s), _derivative(q_d)(s), _derivative(_derivative(q_d))(s)
        tau = inverse_dynamics(robot, q, qd, qdd)
        for load in link_loads(robot):
            tau = tau + load.torque(robot, q, qd)
        return tau

    if robot.damping is None:
        def theta(s):
            return motor_angle(robot, q_d(s) + elastic_deflection(robot, torque(s)))

        def at(s):
            return theta(s), _derivative(theta)(s), _derivative(_derivative(theta))(s)

        return jax.vmap(at)(t)
    x, xd, xdd = _damped_deflection(robot, torque, t)
    phi = jax.vmap(lambda s: jnp.stack([q_d(s), _derivative(q_d)(s), _derivative(_derivative(q_d))(s)]))(t)
    phi = phi + jnp.stack([x, xd, xdd], 1)  # (N, 3, n): phi and its two rates

    def along(p):
        g = lambda s: motor_angle(robot, p[0] + s * p[1] + 0.5 * s**2 * p[2])  # noqa: E731
        value, first = jax.jvp(g, (0.0,), (1.0,))
        return value, first, jax.jvp(_derivative(g), (0.0,), (1.0,))[1]

    return jax.vmap(along)(phi)


def _damped_deflection(robot: Robot, torque: Callable, t: Float[Array, " N"]
                       ) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
    """The deflection `x` of `d xd + kappa(x) = torque(t)` and its two rates at the times `t` (module docstring)."""
    damped = robot.damping > 0
    d = jnp.where(damped, robot.damping, 1.0)
    h = (t[1] - t[0]) / DAMPED_SUBSTEPS
    fine = t[0] + h * jnp.arange((t.shape[0] - 1) * DAMPED_SUBSTEPS + 1)
    tau, taud = jax.vmap(lambda s: jax.jvp(torque, (s,), (1.0,)))(fine)

    def rates(x, k):
        xd = (tau[k] - elastic_torque(robot, x)) / d
        return xd, (taud[k] - elastic_stiffness(robot, x) * xd) / d

    def step(x0, k):
        f0, g0 = rates(x0, k)

        def residual(x1):
            f1, g1 = rates(x1, k + 1)
            return x1 - x0 - 0.5 * h * (f0 + f1) - h**2 / 12 * (g0 - g1)

        x1 = x0 + h * f0 + 0.5 * h**2 * g0
        for _ in range(DAMPED_NEWTON_STEPS):
            r, slope = jax.jvp(residual, (x1,), (jnp.ones_like(x1),))
            x1 = x1 - r / slope
        return x1, x1

    start = elastic_deflection(robot, tau[0])
    x = jnp.concatenate([start[None], jax.lax.scan(step, start, jnp.arange(fine.shape[0] - 1))[1]])
    x = x[::DAMPED_SUBSTEPS]
    sample = slice(None, None, DAMPED_SUBSTEPS)
    xd, xdd = rates(x, sample)
    # undamped joints: x = kappa^{-1}(tau) and its rates by the implicit function
    x_s = elastic_deflection(robot, tau[sample])
    k1 = elastic_stiffness(robot, x_s)
    curvature = jax.jvp(lambda z: elastic_stiffness(robot, z), (x_s,), (jnp.ones_like(x_s),))[1]
    xd_s = taud[sample] / k1
    taudd = jax.vmap(_derivative(_derivative(torque)))(t)
    xdd_s = (taudd - curvature * xd_s**2) / k1
    return jnp.where(damped, x, x_s), jnp.where(damped, xd, xd_s), jnp.where(damped, xdd, xdd_s)
