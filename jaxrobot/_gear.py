"""Non-constant gear ratio with Fourier ripple, eq. 2.9-2.14 (docs/model.md, section 2).

`u(phi) = u0 (1 + sum_j a_j cos(n_j phi) - b_j sin(n_j phi))` (eq. 2.10),
`Xi(phi) = u0 (phi + sum_j (a_j sin(n_j phi) + b_j cos(n_j phi)) / n_j) + U_C` (eq. 2.13)
with `U_C` such that `Xi(0) = 0` (eq. 2.14). `ccw` selects the set of the negative direction;
it broadcasts against the joint axis (a bool or a bool array of shape (..., n)).

How a gear crosses from one set to the other at a reversal is an effect of the model (`jaxrobot.effects`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._robot import Ripple, Robot

NEWTON_STEPS = 4
"""Newton steps of `gear_output` from `phi0 = theta / u0`. With the ripple amplitudes `c_j = |(a_j, b_j)|`,
`rho = sum_j c_j` (`|u / u0 - 1| <= rho`) and `sigma = sum_j n_j c_j` (`|u'| <= u0 sigma`), the start is off by
`e0 <= sum_j 2 c_j / n_j` and each step squares the error: `e_(k+1) <= K e_k^2`, `K = sigma / (2 (1 - rho))`,
so `e_k <= (K e0)^(2^k - 1) e0`. Racer-7: `K e0 <= 5.9e-3`, `e0 <= 1.6e-3` rad (joint 3, ccw), so three steps
reach 4e-19 rad, below rounding; the fourth keeps that for any ripple with `K e0 <= 0.1`."""

_PIO2 = (1.57079632673412561417e00, 6.07710050630396597660e-11, 2.02226624879595063154e-21)
"""pi/2 in three parts, the first two of 33 bits (fdlibm `pio2_1`, `pio2_2`, `pio2_2t`): `k pi/2` is exact
in the first two for `|k| < 2^20`."""
_SIN = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
        2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
"""fdlibm `__kernel_sin` on `|r| <= pi/4`: `sin r = r + r z (S1 + z S2 + ...)`, `z = r^2`."""
_COS = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
        -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)
"""fdlibm `__kernel_cos` on `|r| <= pi/4`: `cos r = 1 - z/2 + z^2 (C1 + z C2 + ...)`."""


def _horner(coef, z):
    p = coef[-1]
    for ci in coef[-2::-1]:
        p = ci + z * p
    return p


@jax.custom_jvp
@jax.jit
def _sincos(x):
    """`(sin x, cos x)` with one shared reduction `x = k pi/2 + r`, within 2.3e-16 for `|x| < 1e6` (the gear
    arguments `n_j phi` stay below 2e3): one argument reduction where `jnp.sin` and `jnp.cos` make one each. Jitted,
    like `fourier_xi_inverse`, so that eager calls run as one op."""
    k = jnp.round(x * (2 / np.pi))
    r = ((x - k * _PIO2[0]) - k * _PIO2[1]) - k * _PIO2[2]
    z = r * r
    s = r + r * z * _horner(_SIN, z)
    c = 1.0 - 0.5 * z + z * z * _horner(_COS, z)
    quadrant = k - 4.0 * jnp.floor(0.25 * k)  # 0..3
    odd = (quadrant == 1.0) | (quadrant == 3.0)
    sin, cos = jnp.where(odd, c, s), jnp.where(odd, s, c)
    return jnp.where(quadrant >= 2.0, -sin, sin), jnp.where((quadrant == 1.0) | (quadrant == 2.0), -cos, cos)


@_sincos.defjvp
def _sincos_jvp(primals, tangents):
    s, c = _sincos(*primals)
    return (s, c), (c * tangents[0], -s * tangents[0])


def _ripple(robot: Robot, ccw: bool | Bool[Array, "*b n"]) -> Ripple:
    if ccw is False:
        return robot.cw
    sel = jnp.asarray(ccw)[..., None]
    return jax.tree.map(lambda cw, cc: jnp.where(sel, cc, cw), robot.cw, robot.ccw)


def _harmonics(orders, a, b, phi):
    """Orders (padding -> 1), coefficients (padding -> 0), `sin` and `cos` of `n_j phi`."""
    used = orders > 0
    n = jnp.where(used, orders, 1.0)
    s, c = _sincos(n * phi[..., None])
    return n, jnp.where(used, a, 0.0), jnp.where(used, b, 0.0), s, c


def fourier_ratio(u0, orders, a, b, phi):
    """`u(phi)` (eq. 2.10) of one Fourier set: `u0` (...), `orders`, `a`, `b` (..., M), 0 = padding."""
    _, a, b, s, c = _harmonics(orders, a, b, phi)
    return u0 * (1.0 + jnp.sum(a * c - b * s, -1))


def fourier_xi(u0, orders, a, b, phi):
    """`Xi(phi)` (eq. 2.13, `Xi(0) = 0`) of one Fourier set (arguments as `fourier_ratio`)."""
    n, a, b, s, c = _harmonics(orders, a, b, phi)
    return u0 * (phi + jnp.sum((a * s + b * (c - 1.0)) / n, -1))


@jax.custom_jvp
@jax.jit
def fourier_xi_inverse(u0, orders, a, b, theta):
    """`phi = Xi^{-1}(theta)` of one Fourier set (arguments as `fourier_ratio`), exact derivatives (custom JVP)."""
    # NEWTON_STEPS steps from theta / u0 on Xi / u0; one sin/cos per harmonic and step, shared by Xi and u.
    # Padded orders are masked (their sin/cos are still computed: shapes stay static).
    used = orders > 0
    n = jnp.where(used, orders, 1.0)
    a, b = jnp.where(used, a, 0.0), jnp.where(used, b, 0.0)
    a_n, b_n = a / n, b / n
    target = theta / u0
    phi = target
    for _ in range(NEWTON_STEPS):
        s, c = _sincos(n * phi[..., None])
        xi_u0 = phi + jnp.sum(a_n * s + b_n * (c - 1.0), -1)
        phi = phi - (xi_u0 - target) / (1.0 + jnp.sum(a * c - b * s, -1))
    return phi


@fourier_xi_inverse.defjvp
def _xi_inverse_jvp(primals, tangents):
    # implicit function theorem on Xi(phi; p) = theta: u(phi) dphi = dtheta - dXi/dp dp
    u0, orders, a, b, theta = primals
    phi = fourier_xi_inverse(*primals)
    _, dxi_params = jax.jvp(lambda *p: fourier_xi(*p, phi), (u0, orders, a, b), tuple(tangents[:4]))
    return phi, (tangents[4] - dxi_params) / fourier_ratio(u0, orders, a, b, phi)


def gear_ratio(
    robot: Robot, phi: Float[Array, "*b n"], ccw: bool | Bool[Array, "*b n"] = False
) -> Float[Array, "*b n"]:
    """Gear ratio `u(phi) = dtheta/dphi` (eq. 2.10)."""
    rip = _ripple(robot, ccw)
    return fourier_ratio(robot.u0, rip.orders, rip.a, rip.b, phi)


def motor_angle(
    robot: Robot, phi: Float[Array, "*b n"], ccw: bool | Bool[Array, "*b n"] = False
) -> Float[Array, "*b n"]:
    """Motor angle `theta = Xi(phi)` of gear output angle `phi` (eq. 2.13), `Xi(0) = 0`."""
    rip = _ripple(robot, ccw)
    return fourier_xi(robot.u0, rip.orders, rip.a, rip.b, phi)


def gear_output(
    robot: Robot,
    theta: Float[Array, "*b n"],
    ccw: bool | Bool[Array, "*b n"] = False,
    rippled: tuple[int, ...] | None = None,
) -> Float[Array, "*b n"]:
    """Gear output angle `phi = Xi^{-1}(theta)`: `NEWTON_STEPS` Newton steps from `theta / u0`.

    Derivatives of every order follow the implicit function (`dphi/dtheta = 1/u(phi)`), not the steps.
    `rippled` (static): the joints (0-based) whose gear may have ripple; the others get `theta / u0`, which
    is exact for a gear without ripple and skips their Newton steps. None: all joints.
    """
    rip = _ripple(robot, ccw)
    shape = jnp.broadcast_shapes(theta.shape, robot.u0.shape, rip.orders.shape[:-1])
    u0 = jnp.broadcast_to(robot.u0, shape)
    theta = jnp.broadcast_to(theta, shape)
    if rippled is not None and tuple(rippled) != tuple(range(shape[-1])):
        idx = np.asarray(sorted(rippled), int)
        plain = theta / u0
        if idx.size == 0:
            return plain
        sub = shape[:-1] + (idx.size,)
        orders, a, b = (jnp.broadcast_to(x[..., idx, :], sub + x.shape[-1:]) for x in (rip.orders, rip.a, rip.b))
        return plain.at[..., idx].set(fourier_xi_inverse(u0[..., idx], orders, a, b, theta[..., idx]))
    orders, a, b = (jnp.broadcast_to(x, shape + x.shape[-1:]) for x in (rip.orders, rip.a, rip.b))
    return fourier_xi_inverse(u0, orders, a, b, theta)
