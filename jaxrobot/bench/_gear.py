"""Virtual test bench for gear-ratio identification: encoder + gyroscope runs (thesis 3.1.1,
docs/model.md, section 5).

One joint turns at a constant motor speed over its usable range, with cycloidal acceleration
ramps at both ends and short rests before and after; the other joints hold a fixed
configuration. The motor follows the commanded angle exactly; the link angles are the
quasi-static rest angles of the as-built robot, `q = phi - kappa^{-1}(g(q))` with
`phi = Xi^{-1}(theta)` (`jaxrobot.measurement.quasi_static_link_angles`), where the moving gear
uses the ripple set of its direction (`cw` for a positive, `ccw` for a negative motor speed). The
20-bit motor encoders are sampled at 1 kHz; a 3-axis gyroscope on the moving link measures the
link's angular velocity in a frame misaligned from the joint axis by `Rx(alpha) Ry(beta)` (eq. 3.3,
`jaxrobot.measurement.sensor_rotation`), with white noise and a small constant bias.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._gear import gear_output, gear_ratio
from .._instruments import Instruments
from .._program_cache import cached_program
from .._robot import Robot
from ..io._instruments import bench_instruments
from ..measurement._gear_run import GearRun
from ..measurement._gyroscope import mount_angular_velocity, sensor_rotation
from ..measurement._model import quasi_static_link_angles

GEAR_RUN_DEFAULTS = {
    1: {"motor_speed_deg_s": 7468.0, "range_deg": 220.0, "centre_deg": 0.0, "validation_speed_deg_s": 3734.0},
    2: {"motor_speed_deg_s": 8300.0, "range_deg": 100.0, "centre_deg": 35.0, "validation_speed_deg_s": 6213.0},
    3: {"motor_speed_deg_s": 4192.0, "range_deg": 53.49, "centre_deg": -85.0, "validation_speed_deg_s": 2096.0},
}
"""Thesis 3.1.2 experiments per joint (1-based): constant motor speed, link range covered at that
speed, centre of that range (joint coordinate) and the slower validation speed. Joint 1: 40 %
and 20 % of its maximum motor speed; joint 2: 40 % and 30 %; joint 3: 20 % as in the thesis,
validated at 10 % (half the identification speed; the thesis did not validate joint 3 at another
speed)."""

HOLD_Q_DEG = (0.0, 0.0, -90.0, 0.0, 90.0, 0.0)
"""Racer-7 configuration [deg, joint coordinates] of the joints that do not move; the default for a
six-joint robot, other robots hold the zero pose clipped into their limits."""

GYRO_BIAS_DEG_S = 0.005
"""Default std of the constant gyroscope bias per axis and run [deg/s] (assumed, small)."""

REST_S = 0.2
"""Rest before and after the motion [s]; lets the processing estimate the gyroscope bias."""


def motion_profile(
    t: Float[Array, " N"], speed: float, travel: float, ramp: float, rest: float
) -> Float[Array, " N"]:
    """Motor displacement [rad] from the start: rest, a cycloidal ramp (zero acceleration at its
    ends) to `speed` [rad/s] over `ramp` s, constant speed for `travel` rad, the mirrored ramp,
    rest. Smooth to second order; the sign of `speed` gives the direction."""
    v = jnp.abs(speed)
    cruise = travel / v
    ramp_len = v * ramp / 2.0

    def up(s):  # displacement after s seconds of the up ramp
        tau = jnp.clip(s / ramp, 0.0, 1.0)
        return v * ramp * (tau**2 / 2.0 + (jnp.cos(2.0 * jnp.pi * tau) - 1.0) / (4.0 * jnp.pi**2))

    s = t - rest
    total = 2.0 * ramp_len + travel
    x = jnp.where(s < ramp, up(s), ramp_len + v * (s - ramp))
    x = jnp.where(s < ramp + cruise, x, total - up(2.0 * ramp + cruise - s))
    x = jnp.where(s <= 0.0, 0.0, jnp.where(s >= 2.0 * ramp + cruise, total, x))
    return jnp.sign(speed) * x


CHUNK = 2048
"""Samples per compiled call of the bench (one compilation serves every run length)."""


KNOT_STEP = 16
"""The gravity deflection `kappa^{-1}(g(q))` (smooth in time) is solved exactly every
`KNOT_STEP` samples, with its rate by `jvp`, and interpolated by Hermite polynomials (third degree) in between; this
leaves out the small share that the ripple itself adds to the deflection (against `jvp` through
the exact fixed point on every sample, the kinematic-error RMS of joints 1-3 moved by < 4e-5 deg/s)."""


def _theta_fn(profile, joint):
    start, speed, travel, ramp, rest = profile
    onehot = jax.nn.one_hot(joint, start.shape[-1])
    return lambda ti: start + onehot * motion_profile(ti, speed, travel, ramp, rest)


@cached_program
def _deflection_knots(robot, profile, t, joint, ccw_vec):
    """Gravity deflection `phi - q` (n,) and its time derivative at times `t`."""
    theta_of = _theta_fn(profile, joint)

    def deflection(ti):
        theta = theta_of(ti)
        return gear_output(robot, theta, ccw_vec) - quasi_static_link_angles(robot, theta, ccw_vec)

    return jax.vmap(lambda ti: jax.jvp(deflection, (ti,), (jnp.ones_like(ti),)))(t)


@cached_program
def _bench_samples(robot, profile, t, joint, ccw_vec, rot_s, delta, delta_dot):
    """Motor angles, link angles, joint rate about its axis and gyroscope-frame angular velocity
    per sample: `q = phi - delta`, `qd = thetad / u(phi) - delta_dot`, `omega = sum_{j <= i} qd_j z_{j-1}`."""
    theta_of = _theta_fn(profile, joint)

    def one(ti, d, dd):
        theta, thetad = jax.jvp(theta_of, (ti,), (jnp.ones_like(ti),))
        phi = gear_output(robot, theta, ccw_vec)
        q = phi - d
        qd = thetad / gear_ratio(robot, phi, ccw_vec) - dd
        omega = mount_angular_velocity(robot, q, qd, joint)
        return theta, q, omega[2], rot_s.T @ omega

    return jax.vmap(one)(t, delta, delta_dot)


def _chunked(fn, t, robot, profile, *args, per_sample=()):
    """`fn(robot, profile, t, *args, *per_sample)` over the samples `t` in fixed chunks, so that
    one compilation serves every run length."""
    n = t.shape[0]
    pad = -n % CHUNK
    padded = [np.concatenate([x, np.repeat(x[-1:], pad, 0)]) for x in (t, *per_sample)]
    parts = [fn(robot, profile, jnp.asarray(padded[0][k:k + CHUNK]), *args,
                *(jnp.asarray(x[k:k + CHUNK]) for x in padded[1:]))
             for k in range(0, n + pad, CHUNK)]
    return [np.concatenate([np.asarray(p[m]) for p in parts])[:n] for m in range(len(parts[0]))]


def _hermite(t, tk, y, yd):
    """Hermite interpolation (third degree) of knots `(tk, y, yd)` on a uniform grid at times `t`."""
    h = tk[1] - tk[0]
    k = np.clip(np.floor((t - tk[0]) / h).astype(int), 0, len(tk) - 2)
    s = ((t - tk[k]) / h)[:, None]
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return (h00 * y[k] + h10 * h * yd[k] + h01 * y[k + 1] + h11 * h * yd[k + 1],
            (6 * s**2 - 6 * s) / h * y[k] + (3 * s**2 - 4 * s + 1) * yd[k]
            + (-6 * s**2 + 6 * s) / h * y[k + 1] + (3 * s**2 - 2 * s) * yd[k + 1])


def gear_runs(
    robot: Robot,
    joint: int,
    *,
    motor_speed_deg_s: float | None = None,
    range_deg: float | None = None,
    centre_deg: float | None = None,
    repetitions: int = 6,
    directions: tuple[str, ...] = ("cw", "ccw"),
    hold_q_deg: tuple[float, ...] | None = None,
    seed: int | jax.Array = 0,
    gyro_bias_deg_s: float = GYRO_BIAS_DEG_S,
    rest_s: float = REST_S,
    instruments: Instruments | None = None,
) -> GearRun:
    """Bench runs of one joint (thesis 3.1.1): `repetitions` runs per direction.

    **Arguments:**
    - `robot`: the as-built robot (`racer7(as_built=True)`).
    - `joint`: 1-based joint index (1..n).
    - `motor_speed_deg_s`, `range_deg`, `centre_deg`: constant motor speed, link range covered
      at that speed and its centre (joint coordinate); defaults `GEAR_RUN_DEFAULTS` (joints 1-3).
      Ramps use the joint's acceleration limit (cycloidal, peak = limit).
    - `directions`: "cw" (positive motor speed) and/or "ccw"; runs alternate between them.
    - `hold_q_deg`: joint coordinates of the joints that do not move (default `HOLD_Q_DEG`).
    - `seed`: int or `jax.random` key for noise and bias.
    - `gyro_bias_deg_s`: std of the constant bias per axis and run.
    - `instruments`: the gyroscope's noise and misalignment, the encoders' counts per revolution and the sample
      time (`gyro_noise`, `gyro_misalignment`, `encoder_counts_per_rev`, `sample_time`); required for a robot
      other than the embedded Racer-7, whose default is its bench's (`jaxrobot.racer7_instruments()`).

    **Returns:** `GearRun` of the `R` runs (leading axis), with their noise-free truth.
    """
    instruments = bench_instruments(robot, instruments, by="gear_runs")
    noise, mis, ts, counts = instruments.require("gyro_noise", "gyro_misalignment", "sample_time",
                                                 "encoder_counts_per_rev", by="gear_runs")
    n_joints = robot.n_joints
    if joint not in range(1, n_joints + 1):
        raise ValueError(f"joint: expected an integer 1..{n_joints}, found {joint!r}")
    if hold_q_deg is None:
        hold_q_deg = HOLD_Q_DEG if n_joints == len(HOLD_Q_DEG) else tuple(
            np.clip(0.0, np.rad2deg(robot.q_min), np.rad2deg(robot.q_max)).tolist())
    dflt = GEAR_RUN_DEFAULTS.get(joint, {})
    if any(v is None for v in (motor_speed_deg_s, range_deg, centre_deg)) and not dflt:
        raise ValueError(f"motor_speed_deg_s, range_deg, centre_deg: no defaults for joint {joint}; pass them")
    speed_deg = float(dflt["motor_speed_deg_s"] if motor_speed_deg_s is None else motor_speed_deg_s)
    rng_deg = float(dflt["range_deg"] if range_deg is None else range_deg)
    centre = float(dflt["centre_deg"] if centre_deg is None else centre_deg)
    if not speed_deg > 0:
        raise ValueError(f"motor_speed_deg_s: expected > 0 deg/s, found {speed_deg}")
    if not rng_deg > 0:
        raise ValueError(f"range_deg: expected > 0 deg, found {rng_deg}")
    if repetitions < 1:
        raise ValueError(f"repetitions: expected >= 1, found {repetitions}")
    bad = [d for d in directions if d not in ("cw", "ccw")]
    if bad or not directions:
        raise ValueError(f"directions: expected a non-empty tuple of 'cw'/'ccw', found {directions!r}")
    if len(hold_q_deg) != n_joints:
        raise ValueError(f"hold_q_deg: expected {n_joints} joint coordinates [deg], found {len(hold_q_deg)}")
    if np.ndim(robot.a) != 1:
        raise ValueError(f"robot: expected a single robot (a of shape (n,)), found a fleet {np.shape(robot.a)}")

    i = joint - 1
    u0 = float(robot.u0[i])
    v_link = math.radians(speed_deg) / u0
    ramp = 2.0 * v_link / float(robot.qdd_max[i])
    lo_link = math.radians(centre - rng_deg / 2.0) - v_link * ramp / 2.0
    hi_link = math.radians(centre + rng_deg / 2.0) + v_link * ramp / 2.0
    q_lo, q_hi = float(robot.q_min[i]), float(robot.q_max[i])
    if lo_link < q_lo or hi_link > q_hi:
        raise ValueError(
            f"range_deg/centre_deg: joint {joint} would move over [{math.degrees(lo_link):.1f}, "
            f"{math.degrees(hi_link):.1f}] deg incl. ramps, beyond its limits [{math.degrees(q_lo):.1f}, "
            f"{math.degrees(q_hi):.1f}] deg; shorten the range or move its centre")
    travel = math.radians(rng_deg) * u0  # motor travel at constant speed
    duration = 2 * rest_s + 2 * ramp + travel / math.radians(speed_deg)
    n = int(math.ceil(duration / ts)) + 1
    t = np.arange(n) * ts  # host-side set-up: no device op to compile

    hold = np.deg2rad(np.asarray(hold_q_deg, float)) * np.asarray(robot.u0)
    dirs = [directions[k % len(directions)] for k in range(repetitions * len(directions))]
    dirs = sorted(dirs, key=lambda d: directions.index(d))
    key = jax.random.PRNGKey(seed) if isinstance(seed, int) else seed
    rot_s = jax.jit(sensor_rotation)(jnp.asarray(mis))
    out = {k: [] for k in ("theta", "gyro", "q", "rate", "gyro_true", "bias")}
    motion = {}  # the noise-free signals depend on the direction only: computed once per direction
    for k, d in enumerate(dirs):
        if d not in motion:
            sign = 1.0 if d == "cw" else -1.0
            start, ccw_vec = hold.copy(), np.zeros(n_joints, bool)
            start[i], ccw_vec[i] = (lo_link if d == "cw" else hi_link) * u0, d == "ccw"
            args = (start, sign * math.radians(speed_deg), travel, ramp, rest_s)
            tk = np.arange(0.0, float(t[-1]) + 2 * KNOT_STEP * ts, KNOT_STEP * ts)
            dk, ddk = _chunked(_deflection_knots, tk, robot, args, jnp.asarray(i), ccw_vec)
            delta, delta_dot = _hermite(np.asarray(t), tk, dk, ddk)
            motion[d] = _chunked(_bench_samples, np.asarray(t), robot, args, jnp.asarray(i), ccw_vec,
                                 rot_s, per_sample=(delta, delta_dot))
            if not np.all(np.isfinite(motion[d][1])):
                raise ValueError(f"robot: the rest link angles are not finite for joint {joint}, {d} runs")
        theta, q, rate, g_true = motion[d]
        k_noise, k_bias = jax.random.split(jax.random.fold_in(key, k))
        bias = jnp.deg2rad(gyro_bias_deg_s) * jax.random.normal(k_bias, (3,))
        gyro = g_true + np.asarray(bias) + noise * np.asarray(jax.random.normal(k_noise, g_true.shape))
        quant = instruments.encoder_quantum
        out["theta"].append(np.round(np.asarray(theta) / quant) * quant)
        out["gyro"].append(np.asarray(gyro))
        out["q"].append(np.asarray(q))
        out["rate"].append(np.asarray(rate))
        out["gyro_true"].append(np.asarray(g_true))
        out["bias"].append(np.asarray(bias))
    meta = {
        "joint": joint, "motor_speed_deg_s": speed_deg, "range_deg": rng_deg, "centre_deg": centre,
        "ramp_s": ramp, "rest_s": rest_s, "sample_time_s": ts, "encoder_counts_per_rev": counts,
        "gyro_noise_deg_s": float(np.rad2deg(noise)), "gyro_bias_deg_s": np.rad2deg(np.stack(out["bias"])),
        "misalignment_rad": mis, "hold_q_deg": tuple(hold_q_deg), "directions": tuple(dirs),
        "seed": seed if isinstance(seed, int) else None,
    }
    return GearRun(
        t=np.asarray(t), theta=np.stack(out["theta"]), gyro=np.stack(out["gyro"]),
        ccw=np.array([d == "ccw" for d in dirs]), link_angles=np.stack(out["q"]),
        link_rate=np.stack(out["rate"]), gyro_true=np.stack(out["gyro_true"]), metadata=meta)
