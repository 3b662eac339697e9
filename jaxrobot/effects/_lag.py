"""Velocity-loop lag: motor i follows its command through the first-order lag `tau_i thetad_m + theta_m = theta_cmd`,
and its encoder reports `theta_m` (the robot file's `[motors] velocity_lag_s`, `Robot.motor_lag`; docs/model.md (B.7)).

With the quintic command of an interval (`jaxrobot._hermite`) the lag is solved exactly:
`theta_m = theta_p + (theta_m(t_k) - theta_p(t_k)) exp(-(t - t_k)/tau)` with the particular solution
`theta_p = sum_j (-tau)^j theta_cmd^(j)` (j <= 5, the series ends for a quintic). It is smooth in `tau` at 0
(`dtheta_m/dtau = -thetad_cmd` there), so a lag can be fitted from none. Its terms grow as `(tau/h)^j` times the
command's j-th difference and cancel against the decay, so rounding grows with `tau/h` (tested to `tau = 3 h`).
`lag_command` inverts this step: the command whose lagged motor passes the samples of a planned motor trajectory.
The planning model's motor angle is the one after the lag; the OCP's thesis cost weighs the command's acceleration
`u + tau ud` (`MotorLag.command_penalty`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._hermite import HERMITE, check_command, power_derivatives
from .._robot import Robot
from ._effect import Fail, MotorResponse, Parameter


def _lag_response(
    knots: Float[Array, "6 n"], tau: Float[Array, " n"], m0: Float[Array, " n"], s: np.ndarray, h: Float[Array, ""]
) -> tuple[Float[Array, "S n"], Float[Array, "S n"]]:
    """Motor angles and rates at the fractions `s` (S,), `s[0] = 0`, of an interval of length `h` [s] with the
    Hermite `knots` of its command, through the lags `tau` [s] from the motor angles `m0` at its start (module
    docstring)."""
    derivs = jnp.einsum("sjk,ik,in->sjn", power_derivatives(s, 7), HERMITE, knots)  # d^j/ds^j command, j <= 6
    powers = (-tau / h)[None] ** np.arange(6)[:, None]  # (-tau/h)^j: (6, n)
    theta_p = jnp.einsum("jn,sjn->sn", powers, derivs[:, :6])
    thetad_p = jnp.einsum("jn,sjn->sn", powers, derivs[:, 1:]) / h
    lagged = tau > 0
    tau_safe = jnp.where(lagged, tau, 1.0)
    decay = jnp.where(lagged, jnp.exp(-np.asarray(s, float)[:, None] * h / tau_safe), 0.0)
    start = m0 - theta_p[0]
    return theta_p + start * decay, thetad_p - jnp.where(lagged, start / tau_safe, 0.0) * decay


def _lag_step_weights(tau: Float[Array, " n"], h: Float[Array, ""]) -> tuple[Float[Array, "6 n"], Float[Array, " n"]]:
    """The exact step of `_lag_response` over a whole interval: the motor angle at its end is
    `sum_i a[i] knots[i] + decay m0` (per joint, `tau > 0`) for the Hermite `knots` of its command and the start
    `m0`."""
    ends = np.einsum("sjk,ik->sij", power_derivatives(np.array([0.0, 1.0]), 6), HERMITE)  # d^j/ds^j of knot i
    powers = (-tau / h)[None] ** np.arange(6)[:, None]  # (6, n)
    w = jnp.einsum("sij,jn->sin", ends, powers)  # the particular solution's weights at s = 0, 1
    decay = jnp.exp(-h / tau)
    return w[1] - decay * w[0], decay


def lag_command(robot: Robot, t: Float[Array, " N"], theta: Float[Array, "N n"], thetad: Float[Array, "N n"],
                thetadd: Float[Array, "N n"]) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
    """The command `(theta_c, thetad_c, thetadd_c)` (N, n) at the sample times `t` (uniform) whose motors, after the
    velocity-loop lags `robot.motor_lag` as `simulate` solves them, pass every sample with the angles, rates and
    accelerations `(theta, thetad, thetadd)` of a motor trajectory that starts at rest; the trajectory itself where
    the robot has no lag (None, or a motor's `tau = 0`).

    From `tau thetad_m + theta_m = theta_c`: `theta_c = theta + tau thetad` and `thetad_c = thetad + tau thetadd` at
    each sample; `thetadd_c` (which sets the motor's jerk there) by the exact step of each interval (module
    docstring) that takes the motor from `theta_k` to `theta_{k+1}`, one linear recursion per motor from
    `thetadd_c[0] = thetadd[0] + tau jerk_0` (the jerk of the Hermite interpolant of `theta` at `t[0]`). The
    recursion's free mode alternates and decays by a factor `|a2 / a5| < 1` per sample (0.95 at `tau = 3 h`), so
    rounding does not grow; `thetadd_c` is resolved to ~`eps |theta| / (a5 h^2)` (1e-5 rad/s^2 at `tau = 3 h`, where it
    moves the motor by 1e-14 rad). docs/model.md (B.7)."""
    t, theta, thetad, thetadd = check_command(robot, "lag_command", t, theta, thetad, thetadd)
    if robot.motor_lag is None:
        return theta, thetad, thetadd
    h = t[1] - t[0]
    lagged = robot.motor_lag > 0
    tau = jnp.where(lagged, robot.motor_lag, h)
    a, _ = _lag_step_weights(tau, h)
    rate = thetad + tau * thetadd
    step = theta[1:] - theta[:-1]
    # theta_{k+1} - decay theta_k minus the value and rate knots' part, with a0 + a3 = 1 - decay
    rhs = ((1 - a[3]) * step - tau * (a[0] * thetad[:-1] + a[3] * thetad[1:])
           - h * (a[1] * rate[:-1] + a[4] * rate[1:])) / h**2
    jerk0 = jnp.asarray(HERMITE[:, 3] * 6, float) @ jnp.stack(
        [theta[0], thetad[0] * h, thetadd[0] * h**2, theta[1], thetad[1] * h, thetadd[1] * h**2]) / h**3

    def advance(acc, r):
        nxt = (r - a[2] * acc) / a[5]
        return nxt, nxt

    acc0 = thetadd[0] + tau * jerk0
    acc = jnp.concatenate([acc0[None], jax.lax.scan(advance, acc0, rhs)[1]])
    return (jnp.where(lagged, theta + tau * thetad, theta), jnp.where(lagged, rate, thetad),
            jnp.where(lagged, acc, thetadd))


class MotorLag(MotorResponse):
    name = "velocity-loop lag"
    fields = ("motor_lag",)
    parameters = (Parameter("lag", "motor_lag", 1e-3, "s", True, "velocity-loop lag, motor"),)

    def schema(self, n):
        return {"?motors": {"?velocity_lag_s": (n,)}}

    def check(self, data: dict, n: int, fail: Fail) -> None:
        motors = data.get("motors", {})
        if "velocity_lag_s" in motors and np.any(np.asarray(motors["velocity_lag_s"], float) < 0):
            fail("motors.velocity_lag_s", "velocity-loop time constants >= 0 s (0: the motor follows its command "
                 "exactly)", motors["velocity_lag_s"])

    def read(self, data):
        motors = data.get("motors", {})
        return {"motor_lag": jnp.asarray(motors["velocity_lag_s"], float) if "velocity_lag_s" in motors else None}

    def write(self, robot):
        if robot.motor_lag is None:
            return {}
        return {"motors": {"velocity_lag_s": np.asarray(robot.motor_lag, float).tolist()}}

    def motion(self, robot, knots, start, s, h):
        return _lag_response(knots, robot.motor_lag, start, s, h)

    def command(self, robot, t, theta, thetad, thetadd):
        return lag_command(robot, t, theta, thetad, thetadd)

    def command_penalty(self, robot, u, ts):
        return jnp.sum((robot.motor_lag * (u[1:] - u[:-1]) / ts) ** 2)

    def command_edge_weight(self, robot, ts):
        return (robot.motor_lag / ts) ** 2


MOTOR_LAG = MotorLag()
"""The velocity-loop lag (`Robot.motor_lag`)."""
