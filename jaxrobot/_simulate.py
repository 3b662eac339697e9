"""Fixed-step simulation of the elastic-joint model for a commanded motor trajectory.

The motor follows the commanded `theta(t)` exactly (ideal velocity loop, thesis ch. 4; a lag below), so
the state is the link side `(q, qd)` of eq. 2.23a. Between samples the command is the quintic
Hermite interpolant of `(theta, thetad, thetadd)`, so it is C2 in time.

Scheme: classic 4th-order Runge-Kutta with `substeps` steps per sample. Without joint damping
the elastic modes are undamped oscillations with eigenvalues `±iω` on the imaginary
axis (ω up to ~2.6e3 rad/s for the Racer-7, `jaxrobot info` prints it). RK4's stability region
covers the imaginary axis up to |hω| = 2.83, and its amplitude error per step is
~(hω)^6/144, so h = 0.1 ms (10 substeps at 1 ms, hω ≈ 0.26) keeps the modes stable and their
amplitude exact to ~2e-6 per step, while the forced motion is integrated at 4th order. An
implicit A-stable scheme (trapezoidal) would need a Newton solve of the 12-state system per
step and damps nothing more here; it buys nothing for an undamped model at this step (damping moves
the eigenvalues into the left half-plane, where the same steps stay stable).

Dynamic effects of the robot (`Robot.motor_lag`, `Robot.damping`; None leaves the code above untouched):

- Velocity-loop lag: `tau thetad_m + theta_m = theta_cmd` per motor, with the quintic command of an interval,
  is solved exactly: `theta_m = theta_p + (theta_m(t_k) - theta_p(t_k)) exp(-(t - t_k)/tau)` with the particular
  solution `theta_p = sum_j (-tau)^j theta_cmd^(j)` (j <= 5, the series ends for a quintic). It is smooth in
  `tau` at 0 (`dtheta_m/dtau = -thetad_cmd` there), so a lag can be fitted from none. Its terms grow as
  `(tau/h)^j` times the command's j-th difference and cancel against the decay, so rounding grows with
  `tau/h` (tested to `tau = 3 h`). `lag_command` inverts this step: the command whose lagged motor passes the
  samples of a planned motor trajectory.
- Joint damping: the link receives `d (phid - qd)` besides `kappa(phi - q)`, `phid` the gear output's rate
  along the motor rate `thetad_m` (at a fixed flank weight where `directional`).
- Link-side friction (`Robot.viscous_friction`, `Robot.coulomb_friction`): the link receives `-link_friction(qd)`,
  smooth in `qd` (`Robot.friction_velocity`), so the scheme keeps its order through a reversal and at rest.

`directional=True` adds the flank of each gear as a state (docs/model.md (B.0)): the play operator runs
along the motor angle at every stage point of the scheme, and the gear output is `flank_output` at its
flank weight. The weight moves only with motor travel (never with time or the sign of a rate), and is flat
(C2) where a transition starts or ends, so a motor at rest keeps its flank and the scheme keeps its order.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._dynamics import link_acceleration
from ._elasticity import require_elastic
from ._gear import flank_output, flank_weight, gear_output, play, play_start, reversal_travel
from ._robot import Robot
from .effects import joint_torques
from .measurement._model import rest_link_angles

_HERMITE = np.array([
    [1, 0, 0, -10, 15, -6], [0, 1, 0, -6, 8, -3], [0, 0, 0.5, -1.5, 1.5, -0.5],
    [0, 0, 0, 10, -15, 6], [0, 0, 0, -4, 7, -3], [0, 0, 0, 0.5, -1, 0.5],
])
"""Quintic Hermite basis: row i holds the coefficients of `s^0..s^5` of the weight of knot i of
`(p0, v0 h, a0 h^2, p1, v1 h, a1 h^2)` on the unit fraction `s`."""


def _power_derivatives(s: np.ndarray, orders: int) -> np.ndarray:
    """`d^j/ds^j s^k` at the fractions `s`: (len(s), orders, 6) for j < orders, k = 0..5."""
    k, j = np.arange(6)[None, None], np.arange(orders)[None, :, None]
    fall = np.array([[math.perm(kk, jj) for kk in range(6)] for jj in range(orders)], float)
    return np.where(k >= j, fall * np.asarray(s, float)[:, None, None] ** np.maximum(k - j, 0), 0.0)


def _hermite_weights(s: np.ndarray) -> np.ndarray:
    """Quintic Hermite basis (value, rate, acceleration at 0 and 1) at fractions `s`: (len(s), 6, 3).

    Returns weights `w[s, i, j]` for `(p0, v0 h, a0 h^2, p1, v1 h, a1 h^2)` and derivative
    order j = 0, 1, 2 (per unit fraction)."""
    powers = np.stack([s**k for k in range(6)], -1)
    d1 = np.stack([k * s ** max(k - 1, 0) for k in range(6)], -1)
    d2 = np.stack([k * (k - 1) * s ** max(k - 2, 0) for k in range(6)], -1)
    return np.stack([powers @ _HERMITE.T, d1 @ _HERMITE.T, d2 @ _HERMITE.T], -1)


def _lag_response(
    knots: Float[Array, "6 n"], tau: Float[Array, " n"], m0: Float[Array, " n"], s: np.ndarray, h: Float[Array, ""]
) -> tuple[Float[Array, "S n"], Float[Array, "S n"]]:
    """Motor angles and rates at the fractions `s` (S,), `s[0] = 0`, of an interval of length `h` [s] with the
    Hermite `knots` of its command, through the lags `tau` [s] from the motor angles `m0` at its start (module
    docstring)."""
    derivs = jnp.einsum("sjk,ik,in->sjn", _power_derivatives(s, 7), _HERMITE, knots)  # d^j/ds^j command, j <= 6
    powers = (-tau / h)[None] ** np.arange(6)[:, None]  # (-tau/h)^j: (6, n)
    theta_p = jnp.einsum("jn,sjn->sn", powers, derivs[:, :6])
    thetad_p = jnp.einsum("jn,sjn->sn", powers, derivs[:, 1:]) / h
    lagged = tau > 0
    tau_safe = jnp.where(lagged, tau, 1.0)
    decay = jnp.where(lagged, jnp.exp(-np.asarray(s, float)[:, None] * h / tau_safe), 0.0)
    start = m0 - theta_p[0]
    return theta_p + start * decay, thetad_p - jnp.where(lagged, start / tau_safe, 0.0) * decay


def _command(robot: Robot, caller: str, *arrays) -> tuple[Float[Array, "..."], ...]:
    """`(t, theta, thetad, thetadd)` as float arrays, checked for the shapes (N,) and (N, n)."""
    t, theta, thetad, thetadd = (jnp.asarray(a, float) for a in arrays)
    n = robot.n_joints
    if t.ndim != 1 or theta.shape != t.shape + (n,) or thetad.shape != theta.shape or thetadd.shape != theta.shape:
        raise ValueError(f"{caller}: expected t (N,) and theta, thetad, thetadd (N, {n}), found t {t.shape}, "
                         f"theta {theta.shape}, thetad {thetad.shape}, thetadd {thetadd.shape}")
    return t, theta, thetad, thetadd


def _lag_step_weights(tau: Float[Array, " n"], h: Float[Array, ""]) -> tuple[Float[Array, "6 n"], Float[Array, " n"]]:
    """The exact step of `_lag_response` over a whole interval: the motor angle at its end is
    `sum_i a[i] knots[i] + decay m0` (per joint, `tau > 0`) for the Hermite `knots` of its command and the start
    `m0`."""
    ends = np.einsum("sjk,ik->sij", _power_derivatives(np.array([0.0, 1.0]), 6), _HERMITE)  # d^j/ds^j of knot i
    powers = (-tau / h)[None] ** np.arange(6)[:, None]  # (6, n)
    w = jnp.einsum("sij,jn->sin", ends, powers)  # the particular solution's weights at s = 0, 1
    decay = jnp.exp(-h / tau)
    return w[1] - decay * w[0], decay


def lag_command(
    robot: Robot,
    t: Float[Array, " N"],
    theta: Float[Array, "N n"],
    thetad: Float[Array, "N n"],
    thetadd: Float[Array, "N n"],
) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
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
    t, theta, thetad, thetadd = _command(robot, "lag_command", t, theta, thetad, thetadd)
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
    jerk0 = jnp.asarray(_HERMITE[:, 3] * 6, float) @ jnp.stack(
        [theta[0], thetad[0] * h, thetadd[0] * h**2, theta[1], thetad[1] * h, thetadd[1] * h**2]) / h**3

    def advance(acc, r):
        nxt = (r - a[2] * acc) / a[5]
        return nxt, nxt

    acc0 = thetadd[0] + tau * jerk0
    acc = jnp.concatenate([acc0[None], jax.lax.scan(advance, acc0, rhs)[1]])
    return (jnp.where(lagged, theta + tau * thetad, theta), jnp.where(lagged, rate, thetad),
            jnp.where(lagged, acc, thetadd))


def simulate(
    robot: Robot,
    t: Float[Array, " N"],
    theta: Float[Array, "N n"],
    thetad: Float[Array, "N n"],
    thetadd: Float[Array, "N n"],
    substeps: int = 10,
    q0: Float[Array, " n"] | None = None,
    qd0: Float[Array, " n"] | None = None,
    directional: bool = False,
    ccw0: bool | Bool[Array, " n"] = False,
    travel: Float[Array, " n"] | None = None,
    motor_angles: bool = False,
) -> tuple[Float[Array, "N n"], ...]:
    """Link angles and rates `(q, qd)` at the sample times `t` (uniform) for a commanded motor
    trajectory, integrated by RK4 with `substeps` steps per sample (see module docstring).

    The start defaults to rest: `q0` = link angles held by `theta[0]` under gravity, `qd0 = 0`; lagging motors
    (`robot.motor_lag`) start at `theta[0]`. With `motor_angles=True` the motor angles `theta_m` (N, n) at the
    sample times (what the encoders report; the command where the robot has no lag) come third.
    `directional=True` gives each gear its flank state (the test bench's as-built robot): it starts at rest
    on flank `ccw0` (False: cw, per joint), crosses to the other flank over the motor travel `travel`
    (default `reversal_travel(robot)`) after a reversal and keeps its flank at rest; `q0` defaults to the
    rest pose on that flank. The default uses the cw set throughout (the planning model, eq. 4.1).
    """
    t, theta, thetad, thetadd = _command(robot, "simulate", t, theta, thetad, thetadd)
    n = robot.n_joints
    require_elastic(robot, "simulate")
    if substeps < 1:
        raise ValueError(f"simulate: substeps must be >= 1, found {substeps}")
    h = t[1] - t[0]
    if directional:
        q0 = rest_link_angles(robot, theta[0], jnp.broadcast_to(ccw0, (n,)), throw=True) if q0 is None else q0
        wt = reversal_travel(robot) if travel is None else jnp.asarray(travel, float)
        p0 = play_start(theta[0], wt, ccw0)
    else:
        q0 = rest_link_angles(robot, theta[0], throw=True) if q0 is None else q0
        p0 = jnp.zeros(n)
    qd0 = jnp.zeros(n) if qd0 is None else qd0
    stages = np.arange(2 * substeps + 1) / (2 * substeps)
    w = jnp.asarray(_hermite_weights(stages))  # (S, 6, 3)
    lag, rate_dependent = robot.motor_lag, bool(joint_torques(robot))

    def outputs(p, th_s):
        """The gear output as a function of the stage points' motor angles `th_s` (S, n) (at their flank weights
        where `directional`), and the play state after them."""
        if not directional:
            return (lambda th: gear_output(robot, th)), p

        def advance(p, th):
            p = play(p, th, wt)
            return p, flank_weight(p, th, wt)

        p, sigma = jax.lax.scan(advance, p, th_s)
        return (lambda th: flank_output(robot, th, sigma)), p

    def interval(carry, k):
        state, p, m = carry
        knots = jnp.stack([theta[k], thetad[k] * h, thetadd[k] * h**2,
                           theta[k + 1], thetad[k + 1] * h, thetadd[k + 1] * h**2])  # (6 knots, n joints)
        if lag is None:
            th_s, thd_s = jnp.einsum("si,ij->sj", w[..., 0], knots), jnp.einsum("si,ij->sj", w[..., 1], knots) / h
        else:
            th_s, thd_s = _lag_response(knots, lag, m, stages, h)
        output, p = outputs(p, th_s)
        phi_s, phid_s = jax.jvp(output, (th_s,), (thd_s,)) if rate_dependent else (output(th_s), None)
        dt = h / substeps

        def step(j, state):
            q, qd = state
            i = 2 * j
            f = lambda q, qd, m: (qd, link_acceleration(  # noqa: E731
                robot, q, qd, phi_s[i + m], None if phid_s is None else phid_s[i + m]))
            k1 = f(q, qd, 0)
            k2 = f(q + 0.5 * dt * k1[0], qd + 0.5 * dt * k1[1], 1)
            k3 = f(q + 0.5 * dt * k2[0], qd + 0.5 * dt * k2[1], 1)
            k4 = f(q + dt * k3[0], qd + dt * k3[1], 2)
            return (q + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
                    qd + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))

        state = jax.lax.fori_loop(0, substeps, step, state)
        return (state, p, th_s[-1]), (state, th_s[-1])

    _, ((q, qd), m) = jax.lax.scan(interval, ((q0, qd0), p0, theta[0]), jnp.arange(t.shape[0] - 1))
    out = jnp.concatenate([q0[None], q]), jnp.concatenate([qd0[None], qd])
    return out + (jnp.concatenate([theta[:1], m]),) if motor_angles else out
