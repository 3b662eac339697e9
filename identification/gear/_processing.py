"""Processing of gear runs into the kinematic error (thesis 3.1.1, Fig. 3.1).

`prepare_gear_runs` checks raw runs (encoder + gyroscope) and packs them, padded to a common
length with masks, into a `GearBatch`; `process_gear_runs` then treats all runs of all joints
in one jitted call: acausal Gaussian filter (eq. 3.1-3.2) on both signals, gyroscope bias from
the rests, gyroscope alignment (eq. 3.3, two angles per joint, optimistix Levenberg-Marquardt),
motor rate by central differences, the gravity-deflection rate of the model subtracted, and the
kinematic error (eq. 3.4).

Sign convention (docs/model.md, section 2): `thetad = u(phi) phid`, so the kinematic error in link
units is `omega_e = thetad_f / u0 - phid_f` (the thesis' eq. 3.4 writes `u0 thetad_f` for the
reciprocal ratio).
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from jaxrobot import RESULTS, Ripple, Robot
from jaxrobot.internal import cached_program, check, map_matrices
from jaxrobot.measurement import (
    GearRun,
    gear_run_arrays,
    mount_angular_velocity,
    quasi_static_link_angles,
    sensor_rotation,
)

MOVE_THRESHOLD_RAD = math.radians(1.0)
"""A joint moves in a run if its motor angle spans more than this [rad, motor side]."""
SPEED_TOLERANCE = 0.01
"""Constant-speed segment: smoothed motor speed within this fraction of the cruise speed."""
TRIM_SIGMAS = 4.0
"""The segment is shortened by this many filter widths `sigma_q` at each end (filter edge)."""
PASSBAND = 2.0
"""Orders whose ripple frequency `n |phid| / 2 pi` exceeds `PASSBAND * f_c` count as filtered out
(the Gaussian's amplitude gain `2^(-(f/f_c)^2 / 2)` is 25 % there). Orders between 1.5 and 2 f_c
still carry ripple that a slower run sees almost unfiltered (joint 1's 302-304 at the validation
speed), so they are candidates."""
MIN_CYCLES = 2.0
"""The segment must hold this many cycles of the highest order in the passband."""
MIN_REST_SAMPLES = 50
"""Samples at rest needed to estimate the gyroscope bias (else no bias is removed)."""
REST_TOLERANCE_RAD = 1e-4
"""Motor-side angle band around the first/last sample that counts as standing still [rad]."""
REST_MARGIN_S = 0.05
"""Rest samples closer than this to motion are left out of the bias estimate [s]."""
KNOT_STEP = 16
"""The deflection-rate factor of the model (smooth in time) is evaluated every `KNOT_STEP`
samples and interpolated linearly."""
ALIGN_DECIMATION = 4
"""Every `ALIGN_DECIMATION`-th segment sample enters the alignment (eq. 3.3)."""


class GearBatch(eqx.Module):
    """`R` gear runs padded to `N` samples (arrays; SI units, radians)."""

    theta: Float[Array, "R N n"]
    """Motor angles [rad]."""
    gyro: Float[Array, "R N 3"]
    """Gyroscope angular velocity, sensor frame [rad/s]."""
    valid: Bool[Array, "R N"]
    """True for measured samples, False for padding."""
    segment: Bool[Array, "R N"]
    """Constant-speed segment, trimmed by the filter edge."""
    rest: Bool[Array, "R N"]
    """Samples at rest (bias estimate)."""
    joint: Int[Array, " R"]
    """Moving joint, 0-based."""
    ccw: Bool[Array, " R"]
    """True for runs in the negative direction."""
    align: Bool[Array, " R"]
    """Runs that enter the alignment (eq. 3.3); validation runs do not."""
    ts: Float[Array, " R"]
    """Sampling time [s]."""
    sigma: Float[Array, " R"]
    """Standard deviation `sigma_q` of the Gaussian filter [s] (eq. 3.2)."""
    half_width: int = eqx.field(static=True)
    """Half-width of the discrete filter kernel [samples]."""


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """What `prepare_gear_runs` found in one run (1-based joint)."""

    joint: int
    ccw: bool
    motor_speed_deg_s: float
    segment_deg: float
    max_order: int
    samples: int


def filter_sigma(cutoff_hz: float) -> float:
    """`sigma_q = sqrt(ln 2) / (2 pi f_c)` [s] (eq. 3.2)."""
    return math.sqrt(math.log(2.0)) / (2.0 * math.pi * cutoff_hz)


def check_gear_run(t: np.ndarray, theta: np.ndarray, gyro: np.ndarray, name: str = "run") -> tuple[int, float]:
    """Reject bad runs before any compute; return the moving joint (0-based) and the sample time.

    Raises `ValueError` for wrong shapes, NaN/inf samples, non-increasing or non-uniform time,
    no motion, or more than one moving joint.
    """
    t, theta, gyro = np.asarray(t, float), np.asarray(theta, float), np.asarray(gyro, float)
    n = t.shape[0] if t.ndim == 1 else -1
    if t.ndim != 1 or theta.ndim != 2 or theta.shape[0] != n or gyro.shape != (n, 3):
        raise ValueError(f"{name}: expected t (N,), theta (N, n), gyro (N, 3), found {t.shape}, "
                         f"{theta.shape}, {gyro.shape}")
    if n < 16:
        raise ValueError(f"{name}: expected at least 16 samples, found {n}")
    for label, arr in (("t_s", t[:, None]), ("theta", theta), ("gyro", gyro)):
        bad = ~np.isfinite(arr)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise ValueError(f"{name}: NaN or infinite sample in {label} (column {col}) at sample {row} "
                             f"({int(bad.any(1).sum())} samples affected); remove or repair them")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise ValueError(f"{name}: time must increase strictly; t_s[{k + 1}] = {t[k + 1]} follows "
                         f"t_s[{k}] = {t[k]}")
    ts = float(np.median(dt))
    if np.max(np.abs(dt - ts)) > 0.01 * ts:
        k = int(np.argmax(np.abs(dt - ts)))
        raise ValueError(f"{name}: expected uniform sampling ({ts:g} s), found a step of {dt[k]:g} s "
                         f"at sample {k}; resample the run")
    span = theta.max(0) - theta.min(0)
    moving = np.flatnonzero(span > MOVE_THRESHOLD_RAD)
    if moving.size == 0:
        raise ValueError(f"{name}: no motion: no motor angle changes by more than "
                         f"{math.degrees(MOVE_THRESHOLD_RAD):g} deg; a gear run turns one joint")
    if moving.size > 1:
        joints = ", ".join(str(j + 1) for j in moving)
        raise ValueError(f"{name}: joints {joints} move at once (motor spans "
                         f"{', '.join(f'{math.degrees(span[j]):.1f}' for j in moving)} deg); a gear run "
                         "turns exactly one joint")
    return int(moving[0]), ts


UNIT_TOLERANCE = 0.08
"""Relative agreement of motor rate / u0 with the gyroscope rate that `check_gear_units` demands
(misalignment, ripple and deflection rates change it by well under 1 %)."""
RATE_MISTAKES = {
    "link angles in the motor columns (theta_deg is the motor side: link angle times u0)": "link",
    "radians in the theta _deg columns": np.pi / 180.0,
    "degrees x1000 in the theta _deg columns": 1e3,
    "radians per second in the gyro _deg_s columns": 180.0 / np.pi,
}
"""Common mistakes in a gear run: what they make of `(thetad / u0) / |gyro|` ("link": 1 / u0)."""


def check_gear_units(theta: np.ndarray, gyro: np.ndarray, joint: int, u0: float, ts: float,
                     name: str = "run") -> None:
    """Before any fit: the moving joint's motor rate over `u0` must match the gyroscope's rate
    (both see the link turn) within `UNIT_TOLERANCE`; else name the mistake that explains the
    ratio (`RATE_MISTAKES`) or the ratio found."""
    rate = np.abs(np.gradient(np.asarray(theta, float)[:, joint], ts)) / u0
    gyro_rate = np.linalg.norm(np.asarray(gyro, float), axis=-1)
    moving = rate > 0.5 * np.max(rate)
    ratio = float(np.median(rate[moving]) / max(float(np.median(gyro_rate[moving])), 1e-300))
    if abs(math.log(ratio)) <= math.log1p(UNIT_TOLERANCE):
        return
    found = [text for text, f in RATE_MISTAKES.items()
             if abs(math.log(ratio / (1.0 / u0 if isinstance(f, str) else f))) <= math.log1p(UNIT_TOLERANCE)]
    likely = f"; likely {' or '.join(found)}" if found else ""
    raise ValueError(f"{name}: joint {joint + 1}'s motor rate / u0 is {ratio:.4g} times the gyroscope's rate, "
                     f"expected 1 (motor-side degrees, gyroscope in deg/s){likely}")


def _segment(thetad: np.ndarray, trim: int) -> tuple[slice, float]:
    """Longest run of samples at constant cruise speed, shortened by `trim` at both ends."""
    k = 9
    smooth = np.convolve(thetad, np.ones(k) / k, mode="same")
    cruise = np.median(smooth[np.abs(smooth) > 0.5 * np.max(np.abs(smooth))])
    ok = np.abs(smooth - cruise) <= SPEED_TOLERANCE * abs(cruise)
    best, start, best_len = (0, 0), None, 0
    for i, flag in enumerate(np.append(ok, False)):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            if i - start > best_len:
                best, best_len = (start, i), i - start
            start = None
    lo, hi = best[0] + trim, best[1] - trim
    return slice(lo, max(lo, hi)), float(cruise)


def _rest_samples(theta: np.ndarray, ts: float) -> np.ndarray:
    """Samples at the start or end where the motor stands (within `REST_TOLERANCE_RAD` of its first
    or last angle), at least `REST_MARGIN_S` away from any motion."""
    still = (np.abs(theta - theta[0]) <= REST_TOLERANCE_RAD) | (np.abs(theta - theta[-1]) <= REST_TOLERANCE_RAD)
    margin = int(math.ceil(REST_MARGIN_S / ts))
    moving = np.convolve((~still).astype(float), np.ones(2 * margin + 1), mode="same") > 0
    return still & ~moving


def prepare_gear_runs(
    runs: GearRun | list,
    cutoff_hz: dict[int, float],
    u0: np.ndarray,
    names: list[str] | None = None,
) -> tuple[GearBatch, list[RunInfo]]:
    """Check raw runs and pack them into a padded `GearBatch`.

    **Arguments:**
    - `runs`: a `GearRun` or a list of `GearRun`s and `(t (N,) s, theta (N, n) rad, gyro (N, 3) rad/s)` tuples
      (`jaxrobot.measurement.gear_run_arrays`), lengths may differ.
    - `cutoff_hz`: 3 dB cut-off of the Gaussian filter per 1-based joint (eq. 3.2, Table A.4).
    - `u0`: (n,) basic ratios of the model, to express segment lengths on the link side.
    - `names`: labels for error messages (file names).

    Raises `ValueError` (naming the run) for bad runs, unit mistakes (`check_gear_units`), and for a
    constant-speed segment too short
    to resolve any gear order (`MIN_CYCLES` cycles of the highest order in the passband).
    """
    runs = gear_run_arrays(runs, "runs")
    if not runs:
        raise ValueError("runs: expected at least one gear run, found none")
    names = names or [f"run {k}" for k in range(len(runs))]
    u0 = np.asarray(u0, float)
    infos, packed = [], []
    for (t, theta, gyro), name in zip(runs, names):
        joint, ts = check_gear_run(t, theta, gyro, name)
        if np.shape(theta)[1] != u0.shape[0]:
            raise ValueError(f"{name}: expected motor angles of {u0.shape[0]} joints (theta (N, {u0.shape[0]})), "
                             f"found {np.shape(theta)[1]}")
        check_gear_units(theta, gyro, joint, float(u0[joint]), ts, name)
        if joint + 1 not in cutoff_hz:
            raise ValueError(f"{name}: joint {joint + 1} moves, but no filter cut-off is given for it "
                             f"(have joints {sorted(cutoff_hz)}); add it to [sensors] filter_cutoff_hz")
        sigma = filter_sigma(cutoff_hz[joint + 1])
        th = np.asarray(theta, float)
        thetad = np.gradient(th[:, joint], ts)
        seg, cruise = _segment(thetad, int(math.ceil(TRIM_SIGMAS * sigma / ts)))
        link_speed = abs(cruise) / u0[joint]
        seg_rad = (seg.stop - seg.start) * ts * link_speed
        max_order = int(2.0 * math.pi * PASSBAND * cutoff_hz[joint + 1] / link_speed)
        need = MIN_CYCLES * 2.0 * math.pi / max(max_order, 1)
        if seg_rad < need or seg.stop - seg.start < 32:
            raise ValueError(
                f"{name}: the constant-speed segment of joint {joint + 1} spans {math.degrees(seg_rad):.2f} deg "
                f"({seg.stop - seg.start} samples after trimming the filter edges); resolving any gear order "
                f"at {math.degrees(link_speed):.1f} deg/s needs >= {math.degrees(need):.2f} deg and 32 samples; "
                "record a longer run at constant speed")
        rest = _rest_samples(th[:, joint], ts)
        infos.append(RunInfo(joint + 1, bool(cruise < 0), math.degrees(cruise), math.degrees(seg_rad),
                             max_order, th.shape[0]))
        packed.append((th, np.asarray(gyro, float), seg, rest, joint, ts, sigma))
    n = max(p[0].shape[0] for p in packed)
    r = len(packed)
    theta = np.zeros((r, n, u0.shape[0]))
    gyro = np.zeros((r, n, 3))
    valid, segment, rest = (np.zeros((r, n), bool) for _ in range(3))
    for k, (th, gy, seg, rs, _, _, _) in enumerate(packed):
        m = th.shape[0]
        theta[k, :m], theta[k, m:] = th, th[-1]
        gyro[k, :m] = gy
        valid[k, :m], segment[k, seg], rest[k, :m] = True, True, rs
    half = int(math.ceil(4.0 * max(p[6] / p[5] for p in packed)))
    batch = GearBatch(
        theta=jnp.asarray(theta), gyro=jnp.asarray(gyro), valid=jnp.asarray(valid),
        segment=jnp.asarray(segment), rest=jnp.asarray(rest),
        joint=jnp.asarray([p[4] for p in packed]), ccw=jnp.asarray([i.ccw for i in infos]),
        align=jnp.ones(r, bool),
        ts=jnp.asarray([p[5] for p in packed]), sigma=jnp.asarray([p[6] for p in packed]), half_width=half)
    return batch, infos


def gaussian_kernel(sigma: Float[Array, ""], ts: Float[Array, ""], half_width: int) -> Float[Array, " K"]:
    """Discrete acausal Gaussian impulse response (eq. 3.1), unit sum, `2 half_width + 1` taps."""
    k = jnp.arange(-half_width, half_width + 1) * ts
    g = jnp.exp(-(k**2) / (2.0 * sigma**2))
    return g / jnp.sum(g)


def gaussian_filter(
    x: Float[Array, "N ..."], valid: Bool[Array, " N"], kernel: Float[Array, " K"]
) -> Float[Array, "N ..."]:
    """Acausal Gaussian filter of one run (eq. 3.1-3.2), normalised at the ends of the valid
    samples (zero-phase; padding does not leak in). Written as a sum of shifted copies: XLA's
    CPU convolution is very slow once batched over runs with different kernels."""
    half = (kernel.shape[0] - 1) // 2
    w = valid.astype(x.dtype).reshape(valid.shape + (1,) * (x.ndim - 1))
    pad = [(half, half)] + [(0, 0)] * (x.ndim - 1)
    xp, wp = jnp.pad(x * w, pad), jnp.pad(jnp.broadcast_to(w, w.shape), pad)
    n = x.shape[0]

    def tap(k, acc):
        num, den = acc
        return (num + kernel[k] * jax.lax.dynamic_slice_in_dim(xp, k, n),
                den + kernel[k] * jax.lax.dynamic_slice_in_dim(wp, k, n))

    num, den = jax.lax.fori_loop(0, kernel.shape[0], tap, (jnp.zeros_like(x), jnp.zeros_like(w)))
    return num / jnp.where(den > 0, den, 1.0)


def pinv_psd(a, rcond: float = 1e-13):
    """Pseudo-inverse of a symmetric positive semi-definite matrix (eigenvalues below `rcond` of
    the largest, after scaling to unit diagonal, count as zero: unused columns, collinearity)."""
    d = jnp.sqrt(jnp.diagonal(a))
    d = jnp.where(d > 0, d, 1.0)
    w, v = jnp.linalg.eigh(a / d[:, None] / d[None, :])
    keep = w > rcond * jnp.max(w)
    inv = (v * jnp.where(keep, 1.0 / jnp.where(keep, w, 1.0), 0.0)) @ v.T
    return inv / d[:, None] / d[None, :]


def normal_solve(x: Float[Array, "*b N P"], y: Float[Array, "*b N"], w: Float[Array, "*b N"]):
    """Weighted least squares `min sum w (y - x p)^2` by the normal equations with one step of
    iterative refinement: one small (P, P) system instead of a QR/SVD of the tall (N, P) matrix."""
    a = jnp.einsum("...np,...n,...nq->...pq", x, w, x)
    inv = map_matrices(pinv_psd, a)
    p = jnp.einsum("...pq,...q->...p", inv, jnp.einsum("...np,...n->...p", x, w * y))
    r = y - jnp.einsum("...np,...p->...n", x, p)
    return p + jnp.einsum("...pq,...q->...p", inv, jnp.einsum("...np,...n->...p", x, w * r))


def central_rate(x: Float[Array, " N"], ts: Float[Array, ""]) -> Float[Array, " N"]:
    """Time derivative by central differences (one-sided at the ends)."""
    mid = (x[2:] - x[:-2]) / (2.0 * ts)
    return jnp.concatenate([(x[1:2] - x[:1]) / ts, mid, (x[-1:] - x[-2:-1]) / ts])


def _link_rate_factor(robot: Robot, theta: Float[Array, " n"], joint: Int[Array, ""]) -> Float[Array, ""]:
    """Angular velocity of the moving link about its joint axis per unit motor rate of that joint,
    for the quasi-static model (gravity deflection of all joints included, no ripple)."""
    onehot = jax.nn.one_hot(joint, theta.shape[-1])
    ccw = jnp.zeros(theta.shape[-1], bool)
    q, qd = jax.jvp(lambda th: quasi_static_link_angles(robot, th, ccw), (theta,), (onehot,))
    return mount_angular_velocity(robot, q, qd, joint)[2]


class ProcessedRuns(eqx.Module):
    """Output of `process_gear_runs` (per run `R`, per sample `N`; rad, rad/s)."""

    theta: Float[Array, "R N"]
    """Motor angle of the moving joint."""
    thetad: Float[Array, "R N"]
    """Motor rate by central differences (unfiltered)."""
    phid: Float[Array, "R N"]
    """Gear-output rate: aligned, bias-free gyroscope plus the model's deflection rate (unfiltered)."""
    thetad_f: Float[Array, "R N"]
    """Filtered motor rate."""
    phid_f: Float[Array, "R N"]
    """Filtered gear-output rate."""
    kinematic_error: Float[Array, "R N"]
    """`omega_e = thetad_f / u0 - phid_f` (eq. 3.4) with the model's `u0`."""
    misalignment: Float[Array, "n 2"]
    """Alignment angles `(alpha, beta)` per joint (eq. 3.3); zero for joints without runs."""
    align_result: RESULTS
    """Status of the alignment (`jaxrobot.RESULTS`)."""
    align_steps: Array
    """Levenberg-Marquardt steps of the alignment."""
    bias: Float[Array, "R 3"]
    """Gyroscope bias removed: the rests' mean shrunk towards 0 by the spread of the biases over
    the runs (empirical Bayes, `tau^2 / (tau^2 + se^2)`) [rad/s]."""
    bias_var: Float[Array, "R 3"]
    """Variance of the bias left after the removal [rad^2/s^2] (`tau^2 se^2 / (tau^2 + se^2)`, or
    `tau^2` without rests, with `tau^2` at its upper 2-sigma bound): the run-to-run part of the
    error of `u0`."""
    noise_var: Float[Array, " R"]
    """Variance of the gyroscope's white noise per sample [rad^2/s^2] (from second differences)."""
    kernel_energy: Float[Array, " R"]
    """`sum g_k^2` of each run's filter: white noise of variance s^2 leaves s^2 times this."""


def process_gear_runs(robot: Robot, batch: GearBatch, throw: bool = False) -> ProcessedRuns:
    """Kinematic error of all runs of all joints in one call (thesis Fig. 3.1).

    `robot` is the model (nominal); its ripple is ignored, its `u0`, kinematics, masses and
    stiffness give the gravity-deflection rate that is subtracted.

    `throw`: raise the message of `align_result` (at run time, also under `jit`) when the gyroscope
    alignment (eq. 3.3) did not converge. Default False: the result carries the status.
    """
    proc = _process_gear_runs(robot, batch)
    return check(proc.align_result, proc, throw)


@cached_program
def _process_gear_runs(robot: Robot, batch: GearBatch) -> ProcessedRuns:
    robot = eqx.tree_at(lambda r: (r.cw, r.ccw), robot, (Ripple.none(robot.n_joints), Ripple.none(robot.n_joints)))
    r_idx = jnp.arange(batch.theta.shape[0])
    theta = batch.theta[r_idx, :, batch.joint]
    u0 = robot.u0[batch.joint]
    kernels = jax.vmap(gaussian_kernel, in_axes=(0, 0, None))(batch.sigma, batch.ts, batch.half_width)
    filt = jax.vmap(gaussian_filter)
    thetad = jax.vmap(central_rate)(theta, batch.ts) * batch.valid
    thetad_f = filt(thetad, batch.valid, kernels)

    # gyroscope bias from the rests
    rest = batch.rest & batch.valid
    n_rest = jnp.sum(rest, 1)
    bias = jnp.sum(batch.gyro * rest[..., None], 1) / jnp.maximum(n_rest, 1)[:, None]
    spread = jnp.sqrt(jnp.sum((batch.gyro - bias[:, None, :]) ** 2 * rest[..., None], 1)
                      / jnp.maximum(n_rest - 1, 1)[:, None])
    # shrink each rest estimate by the spread tau^2 of the biases over the runs (empirical Bayes): a
    # small bias is not replaced by the larger error of its estimate, a large one is removed
    has_rest = (n_rest >= MIN_REST_SAMPLES)[:, None]
    se2 = spread**2 / jnp.maximum(n_rest, 1)[:, None]
    w = has_rest.astype(float) * jnp.ones_like(bias)
    tau2 = jnp.maximum(jnp.sum(w * (bias**2 - se2)) / jnp.maximum(jnp.sum(w), 1.0), 0.0)
    shrink = tau2 / jnp.maximum(tau2 + se2, 1e-300)
    bias = jnp.where(has_rest, shrink * bias, 0.0)
    # error variance with tau^2 at its upper 2-sigma bound (a chi-square mean of sum(w) terms)
    tau2_hi = tau2 + 2.0 * jnp.sqrt(2.0 / jnp.maximum(jnp.sum(w), 1.0)) * (tau2 + jnp.sum(w * se2) / jnp.maximum(
        jnp.sum(w), 1.0))
    bias_var = jnp.where(has_rest, tau2_hi * se2 / jnp.maximum(tau2_hi + se2, 1e-300), tau2_hi)
    gyro = (batch.gyro - bias[:, None, :]) * batch.valid[..., None]
    gyro_f = filt(gyro, batch.valid, kernels)

    # alignment, eq. 3.3: Rx(alpha) Ry(beta) omega_G = r e_z, r = +-|omega_G| (sign of the z part)
    sub = (slice(None), slice(None, None, ALIGN_DECIMATION))
    w_sub, mask_sub, joint = gyro_f[sub], (batch.segment & batch.align[:, None])[sub], batch.joint

    def residual(angles, _):
        rot = sensor_rotation(angles)[joint]  # (R, 3, 3)
        aligned = jnp.einsum("rij,rnj->rni", rot, w_sub)
        r = jnp.linalg.norm(w_sub, axis=-1) * jnp.sign(w_sub[..., 2])
        res = (r[..., None] * jnp.array([0.0, 0.0, 1.0]) - aligned) * mask_sub[..., None]
        return res, 1e-9 * angles

    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12, linear_solver=lx.Normal(lx.Cholesky()))
    sol = optx.least_squares(residual, solver, jnp.zeros((robot.n_joints, 2)), max_steps=64, throw=False)
    angles = sol.value
    rot = sensor_rotation(angles)[joint]
    gyro_z = jnp.einsum("rj,rnj->rn", rot[:, 2, :], gyro)

    # white-noise variance of the gyroscope from second differences of the aligned rate
    d2 = gyro_z[:, 2:] - 2 * gyro_z[:, 1:-1] + gyro_z[:, :-2]
    m2 = batch.segment[:, 2:] & batch.segment[:, :-2]
    noise_var = jnp.sum(d2**2 * m2, 1) / jnp.maximum(jnp.sum(m2, 1), 1) / 6.0

    # gravity-deflection rate of the model (thesis "Gravity Impact"): the moving link turns at
    # thetad * factor(theta) instead of thetad / u0; add the difference back to the gyroscope
    knots = batch.theta[:, ::KNOT_STEP]
    factor_k = jax.vmap(jax.vmap(_link_rate_factor, in_axes=(None, 0, None)), in_axes=(None, 0, 0))(
        robot, knots, batch.joint)
    idx = jnp.arange(batch.theta.shape[1])
    factor = jax.vmap(lambda f: jnp.interp(idx, idx[::KNOT_STEP], f))(factor_k)
    phid = (gyro_z + thetad * (1.0 / u0[:, None] - factor)) * batch.valid
    phid_f = filt(phid, batch.valid, kernels)
    return ProcessedRuns(
        theta=theta, thetad=thetad, phid=phid, thetad_f=thetad_f, phid_f=phid_f,
        kinematic_error=thetad_f / u0[:, None] - phid_f, misalignment=angles,
        align_result=RESULTS.promote(sol.result), align_steps=sol.stats["num_steps"], bias=bias, bias_var=bias_var,
        noise_var=noise_var,
        kernel_energy=jnp.sum(kernels**2, 1))


def segment_windows(proc: ProcessedRuns, batch: GearBatch, rows: np.ndarray) -> tuple[ProcessedRuns, GearBatch]:
    """Runs `rows` cut to their constant-speed segment plus the filter's half-width at each end
    (edge helper): a filter output on the segment, of the full run or of the window, is the same,
    and the fits touch nothing else, so they need not carry the rests, ramps and padding."""
    rows = np.asarray(rows)
    seg, valid = np.asarray(batch.segment)[rows], np.asarray(batch.valid)[rows]
    half = batch.half_width
    lo = np.maximum(np.argmax(seg, 1) - half, 0)
    hi = np.minimum(seg.shape[1] - np.argmax(seg[:, ::-1], 1) + half, valid.sum(1))
    width = int(np.max(hi - lo))
    idx = np.minimum(lo[:, None] + np.arange(width), seg.shape[1] - 1)
    inside = np.arange(width)[None, :] < (hi - lo)[:, None]

    def cut(x):
        x = np.asarray(x)[rows]
        return jnp.asarray(np.take_along_axis(x, idx.reshape(idx.shape + (1,) * (x.ndim - 2)), 1))

    per_run = lambda x: jnp.asarray(np.asarray(x)[rows])
    proc = ProcessedRuns(
        theta=cut(proc.theta), thetad=cut(proc.thetad), phid=cut(proc.phid), thetad_f=cut(proc.thetad_f),
        phid_f=cut(proc.phid_f), kinematic_error=cut(proc.kinematic_error), misalignment=proc.misalignment,
        align_result=proc.align_result, align_steps=proc.align_steps, bias=per_run(proc.bias),
        bias_var=per_run(proc.bias_var), noise_var=per_run(proc.noise_var), kernel_energy=per_run(proc.kernel_energy))
    batch = GearBatch(
        theta=cut(batch.theta), gyro=cut(batch.gyro), valid=cut(batch.valid) & inside,
        segment=cut(batch.segment) & inside, rest=cut(batch.rest) & inside, joint=per_run(batch.joint),
        ccw=per_run(batch.ccw), align=per_run(batch.align), ts=per_run(batch.ts), sigma=per_run(batch.sigma),
        half_width=half)
    return proc, batch
