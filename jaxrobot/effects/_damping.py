"""Joint damping: viscous damping `d` of each joint spring, so that the joint transmits `kappa(phi - q) + d (phid - qd)`
(docs/model.md (2.23c); the robot file's `[stiffness] damping`). With it the flat inverse's deflection `x = phi - q`
is no longer algebraic: `d xd + kappa(x) = tau(t)`, `tau = D q̈_d + C q̇_d + g`, a stable first-order equation per
joint (time constant `d / kappa'`), integrated from rest (`x = kappa^{-1}(tau(0))`) by the two-point
Hermite-Obreschkoff rule of order 4 (A-stable: `d / k` may be far below the step) on `DAMPED_SUBSTEPS` steps per
sample, with Newton on each step; `xd` and `xdd` follow from the equation. Undamped joints (`d = 0`) keep
`x = kappa^{-1}(tau)`."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._elasticity import elastic_deflection, elastic_stiffness, elastic_torque
from .._robot import Robot
from ._effect import Fail, JointTorque, Parameter

DAMPED_SUBSTEPS = 10
"""Steps per sample of the damped deflection (module docstring): at 0.1 ms the rule's error, ~`h^4` times the
fifth derivative of the deflection, is below 1e-12 rad for the reference tasks."""
DAMPED_NEWTON_STEPS = 3
"""Newton steps per step of the damped deflection, from the explicit second-order Taylor step (the equation is
linear but for the cubic spring term)."""


def _derivative(fn: Callable) -> Callable:
    return lambda t: jax.jvp(fn, (t,), (jnp.ones_like(t),))[1]


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


class JointDamping(JointTorque):
    name = "joint damping"
    fields = ("damping",)
    parameters = (Parameter("damping", "damping", 10.0, "N m s/rad", True),)

    def schema(self, n):
        return {"?stiffness": {"?damping": (n,)}}

    def check(self, data: dict, n: int, fail: Fail) -> None:
        stiffness = data.get("stiffness", {})
        damping = np.asarray(stiffness.get("damping", np.zeros(n)), float)
        k1 = np.asarray(stiffness.get("k1", np.full(n, np.inf)), float)
        for i in range(n):
            if damping[i] < 0 or (damping[i] > 0 and np.isinf(k1[i])):
                fail(f"stiffness.damping[{i}] (joint {i + 1})",
                     "viscous damping >= 0 N m s/rad of an elastic joint (0 where k1 = inf, a rigid joint)",
                     float(damping[i]))

    def read(self, data):
        stiffness = data.get("stiffness", {})
        return {"damping": jnp.asarray(stiffness["damping"], float) if "damping" in stiffness else None}

    def write(self, robot):
        return {} if robot.damping is None else {"stiffness": {"damping": np.asarray(robot.damping, float).tolist()}}

    def torque(self, robot, qd, phid):
        return robot.damping * (phid - qd)

    def torque_vjp(self, robot, thetad, ratio, ratio_slope):
        def vjp(s):
            damp = robot.damping * s
            return -damp, damp * thetad * ratio_slope, damp / ratio

        return vjp

    def flat_deflection(self, robot, torque, t):
        return _damped_deflection(robot, torque, t)


JOINT_DAMPING = JointDamping()
"""Joint damping (`Robot.damping`)."""
