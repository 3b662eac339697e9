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
contracts by far more than 1e3 per step from the start `theta / u0` (tested to 1e-12 rad)."""


def _ripple(robot: Robot, ccw: bool | Bool[Array, "*b 6"]) -> Ripple:
    if ccw is False:
        return robot.cw
    sel = jnp.asarray(ccw)[..., None]
    return jax.tree.map(lambda cw, cc: jnp.where(sel, cc, cw), robot.cw, robot.ccw)


def _ratio(u0, orders, a, b, phi):
    used = orders > 0
    arg = jnp.where(used, orders, 1.0) * phi[..., None]
    return u0 * (1.0 + jnp.sum(jnp.where(used, a * jnp.cos(arg) - b * jnp.sin(arg), 0.0), -1))


def _xi(u0, orders, a, b, phi):
    used = orders > 0
    n = jnp.where(used, orders, 1.0)
    arg = n * phi[..., None]
    wave = jnp.where(used, (a * jnp.sin(arg) + b * (jnp.cos(arg) - 1.0)) / n, 0.0)
    return u0 * (phi + jnp.sum(wave, -1))


@jax.custom_jvp
def _xi_inverse(u0, orders, a, b, theta):
    phi = theta / u0
    for _ in range(NEWTON_STEPS):
        phi = phi - (_xi(u0, orders, a, b, phi) - theta) / _ratio(u0, orders, a, b, phi)
    return phi


@_xi_inverse.defjvp
def _xi_inverse_jvp(primals, tangents):
    # implicit function theorem on Xi(phi; p) = theta: u(phi) dphi = dtheta - dXi/dp dp
    u0, orders, a, b, theta = primals
    phi = _xi_inverse(*primals)
    _, dxi_params = jax.jvp(lambda *p: _xi(*p, phi), (u0, orders, a, b), tuple(tangents[:4]))
    return phi, (tangents[4] - dxi_params) / _ratio(u0, orders, a, b, phi)


def gear_ratio(
    robot: Robot, phi: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Gear ratio `u(phi) = dtheta/dphi` (eq. 2.10)."""
    rip = _ripple(robot, ccw)
    return _ratio(robot.u0, rip.orders, rip.a, rip.b, phi)


def motor_angle(
    robot: Robot, phi: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Motor angle `theta = Xi(phi)` of gear output angle `phi` (eq. 2.13), `Xi(0) = 0`."""
    rip = _ripple(robot, ccw)
    return _xi(robot.u0, rip.orders, rip.a, rip.b, phi)


def gear_output(
    robot: Robot, theta: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Gear output angle `phi = Xi^{-1}(theta)`, Newton's method from `theta / u0`.

    Derivatives of every order follow the implicit function (`dphi/dtheta = 1/u(phi)`).
    """
    rip = _ripple(robot, ccw)
    shape = jnp.broadcast_shapes(theta.shape, robot.u0.shape, rip.orders.shape[:-1])
    u0 = jnp.broadcast_to(robot.u0, shape)
    orders, a, b = (jnp.broadcast_to(x, shape + x.shape[-1:]) for x in (rip.orders, rip.a, rip.b))
    return _xi_inverse(u0, orders, a, b, jnp.broadcast_to(theta, shape))
