"""Non-constant gear ratio with Fourier ripple, eq. 2.9-2.14 (SPEC.md, "Gear").

`u(phi) = u0 (1 + sum_j a_j cos(n_j phi) - b_j sin(n_j phi))` (eq. 2.10),
`Xi(phi) = u0 (phi + sum_j (a_j sin(n_j phi) + b_j cos(n_j phi)) / n_j) + U_C` (eq. 2.13)
with `U_C` such that `Xi(0) = 0` (eq. 2.14). `ccw` selects the set of the negative direction;
it broadcasts against the joint axis (a bool or a bool array of shape (..., 6)).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._robot import Ripple, Robot

NEWTON_STEPS = 6
"""Newton steps of `gear_output`; the ripple keeps `u` within a few % of `u0`, so the error
contracts by far more than 1e3 per step from the start `theta / u0` (tested to 1e-13 rad)."""


def _ripple(robot: Robot, ccw: bool | Bool[Array, "*b 6"]) -> Ripple:
    if ccw is False:
        return robot.cw
    sel = jnp.asarray(ccw)[..., None]
    return jax.tree.map(lambda cw, cc: jnp.where(sel, cc, cw), robot.cw, robot.ccw)


def _harmonics(rip: Ripple, phi: Float[Array, "*b 6"]):
    n = rip.orders
    used = n > 0
    n_safe = jnp.where(used, n, 1.0)
    arg = n_safe * phi[..., None]
    return used, n_safe, jnp.cos(arg), jnp.sin(arg)


def gear_ratio(
    robot: Robot, phi: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Gear ratio `u(phi) = dtheta/dphi` (eq. 2.10)."""
    rip = _ripple(robot, ccw)
    used, _, c, s = _harmonics(rip, phi)
    return robot.u0 * (1.0 + jnp.sum(jnp.where(used, rip.a * c - rip.b * s, 0.0), -1))


def motor_angle(
    robot: Robot, phi: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Motor angle `theta = Xi(phi)` of gear output angle `phi` (eq. 2.13), `Xi(0) = 0`."""
    rip = _ripple(robot, ccw)
    used, n, c, s = _harmonics(rip, phi)
    wave = jnp.sum(jnp.where(used, (rip.a * s + rip.b * (c - 1.0)) / n, 0.0), -1)
    return robot.u0 * (phi + wave)


def gear_output(
    robot: Robot, theta: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Gear output angle `phi = Xi^{-1}(theta)` by Newton's method from `theta / u0`.

    Differentiable: the last Newton step carries the derivative of the implicit function
    (`dphi/dtheta = 1/u(phi)`, `dphi/dp = -(dXi/dp)/u`).
    """
    phi = jax.lax.stop_gradient(theta / robot.u0)
    sg_robot = jax.lax.stop_gradient(robot)
    sg_theta = jax.lax.stop_gradient(theta)
    for _ in range(NEWTON_STEPS):
        phi = phi - (motor_angle(sg_robot, phi, ccw) - sg_theta) / gear_ratio(sg_robot, phi, ccw)
    return phi - (motor_angle(robot, phi, ccw) - theta) / gear_ratio(robot, phi, ccw)
