"""Nonlinear joint stiffness `kappa(x) = k1 x + k3 x^3` (eq. 2.17-2.18, docs/model.md (2.17)).

The gear applies `kappa(phi - q)` to the link and `-kappa(phi - q)` to the motor. The robot stores
the compliance form `x + e x^3 = c kappa` (`c = 1/k1`, `e = k3/k1`): a rigid joint (a description
without `[stiffness]`) has `c = 0`, deflects by zero and is differentiable in `c` there.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._robot import Robot

NEWTON_STEPS = 8
"""Newton steps of `elastic_deflection`; started above the root of the convex branch, the
iteration decreases monotonically and quadratically (tested to 1e-12 relative)."""


def elastic_torque(robot: Robot, x: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """`kappa(x) = k1 x + k3 x^3 = (x + e x^3) / c` [N m] for a deflection `x = phi - q` [rad]
    (elastic joints, `c > 0`)."""
    return (x + robot.e * x**3) / robot.c


@jax.custom_jvp
def _deflection(k1, k3, tau):
    t = jnp.abs(tau)
    x = jnp.minimum(t / k1, jnp.where(k3 > 0, jnp.cbrt(t / jnp.where(k3 > 0, k3, 1.0)), jnp.inf))
    for _ in range(NEWTON_STEPS):
        x = x - (k1 * x + k3 * x**3 - t) / (k1 + 3.0 * k3 * x**2)
    return jnp.sign(tau) * x


@_deflection.defjvp
def _deflection_jvp(primals, tangents):
    # kappa(x; k1, k3) = tau  =>  kappa'(x) dx = dtau - x dk1 - x^3 dk3
    k1, k3, tau = primals
    dk1, dk3, dtau = tangents
    x = _deflection(k1, k3, tau)
    return x, (dtau - x * dk1 - x**3 * dk3) / (k1 + 3.0 * k3 * x**2)


def compliance_deflection(
    c: Float[Array, "*b n"], e: Float[Array, "*b n"], tau: Float[Array, "*b n"]
) -> Float[Array, "*b n"]:
    """Deflection `x` [rad] with `x + e x^3 = c tau`: `kappa^{-1}(tau)` in compliance form.

    `c = 1/k1` [rad/(N m)], `e = k3/k1` [1/rad^2]; `c = 0` is a rigid joint (`x = 0`) with finite
    derivatives in `c`, so a compliance can be identified starting from a rigid joint.
    """
    shape = jnp.broadcast_shapes(tau.shape, jnp.shape(c), jnp.shape(e))
    c, e, tau = (jnp.broadcast_to(x, shape) for x in (c, e, tau))
    return _deflection(jnp.ones(shape), e, c * tau)


def elastic_deflection(robot: Robot, tau: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """`kappa^{-1}(tau)`: the deflection [rad] at which the joint transmits `tau` [N m].

    Newton on `|x|` from `min(|tau|/k1, cbrt(|tau|/k3))`, which lies above the root of the
    convex branch; derivatives of every order follow the implicit function. Rigid joints
    (`c = 0`) give 0.
    """
    return compliance_deflection(robot.c, robot.e, tau)


def elastic_stiffness(robot: Robot, x: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """`kappa'(x) = k1 + 3 k3 x^2 = (1 + 3 e x^2) / c` [N m/rad] at the deflection `x = phi - q` [rad];
    `inf` for a rigid joint (`c = 0`), with finite derivatives there."""
    rigid = robot.c == 0
    return jnp.where(rigid, jnp.inf, (1.0 + 3.0 * robot.e * x**2) / jnp.where(rigid, 1.0, robot.c))


def elastic_torque_and_stiffness(
    robot: Robot, x: Float[Array, "*b n"]
) -> tuple[Float[Array, "*b n"], Float[Array, "*b n"]]:
    """The joint springs at the deflections `x = phi - q` [rad]: their torques `kappa(x)` [N m] (`elastic_torque`) and
    slopes `kappa'(x)` [N m/rad] (`elastic_stiffness`), as the link side's dynamics and its derivatives take them."""
    return elastic_torque(robot, x), elastic_stiffness(robot, x)


def require_elastic(robot: Robot, user: str) -> None:
    """Raise if a concrete `robot` has rigid joints (`c = 0`): `user` integrates the elastic model."""
    c = robot.c
    if isinstance(c, jax.core.Tracer):
        return
    rigid = np.flatnonzero(np.any(np.reshape(np.asarray(c), (-1, robot.n_joints)) == 0, 0))
    if rigid.size:
        raise ValueError(f"{user}: needs elastic joints (finite k1 [N m/rad], the [stiffness] section of the robot "
                         f"file); found rigid joints {(rigid + 1).tolist()} (k1 = inf)")
