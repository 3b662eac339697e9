"""Benchmark: are the predicted error bands of a plan on the robot calibrated? (`planning.predict_on_robot`)

R as-built robots of the bench (`jaxrobot.bench.draw_fleet` around the nominal Racer-7, seed 0), each measured by
the tracker at its own 63 random feasible poses (`fleet_measurements`: the first 50 identify, the last 13
validate), calibrated with the default parameter set (`calibrate`; its covariance and validation residual become
the model's `[uncertainty]`); then the line is planned on each calibrated model (the flat inverse of the model;
for the first `--ocp-robots` also `plan_task` at nu = 1e-14 on the gears' flanks) and simulated on the robot's
truth with its gears' flanks as states. Reported: how often the true largest error of the plan on its robot lies
at or below the predicted 95th percentile (goal 90-98 %), the median p95 over the median true error (goal <= 2),
and the cost of the prediction beside the plan's. With `--methods`, the first robot's prediction also by forward
mode through the whole simulation (`method="simulation"`), its p50/p95 and time beside the default's.

With `--independent`, also the robots of `../shared/independent` (`_independent_cases`: each set with calibration
poses and a truth, 6 and 7 joints), in their own section; with the bench's, a pooled summary over the goal's
population (`_pooled`: each robot once, the bench's with their flat-inverse plan). With `--alternatives` also, per
independent robot, the p95 of two other readings of its calibration (`_shrunk`, `_field_p95`).

Run: `python benchmarks/bench_coverage.py [--robots 50] [--ocp-robots 5] [--methods] [--independent
[--alternatives]]` (writes benchmarks/results_coverage.md, all of it from this run; `--robots 0 --independent`: the
independent robots only).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
import planning as pl
from identification import calibrate
from identification.calibration._demo import fleet_measurements
from jaxrobot.io import read_poses
from jaxrobot.measurement import measured_pose
from planning._prediction import DRAWS, METHODS, _linearised, deviation_draws

OUT = Path(__file__).with_name("results_coverage.md")
POSES, VALIDATION = 50, 13
NU = 1e-14


def _plan(model, truth, uncertainty, kind: str) -> tuple[pl.RobotPrediction, float, float, float]:
    """The line planned on `model` (`kind` "ocp" or "flat"), simulated on `truth` with flanks: the prediction, the
    true largest error [m], the plan's time and the prediction's [s]."""
    path = pl.reference_path("line", jr.read_description(None))
    if kind == "ocp":
        stages = {}
        start = time.perf_counter()
        res = pl.plan_task(model, truth, path, NU, directional=True, timing=False, uncertainty=uncertainty,
                           on_event=lambda e: stages.__setitem__(e.stage, e.elapsed))
        if not res.converged:
            raise RuntimeError(f"the OCP did not converge: {jr.status_name(res.status)}")
        total = time.perf_counter() - start
        true = float(res.errors.position_max[res.names.index("ocp")])
        return res.prediction, true, total - stages["prediction"], stages["prediction"]
    start = time.perf_counter()
    jp = pl.joint_path(model, path)
    traj = pl.flat_motor_trajectory(model, jp)
    plan_s = time.perf_counter() - start
    true = float(pl.evaluate_on_plant(truth, jp, {"flat": traj}, directional=True)["flat"].position_max)
    start = time.perf_counter()
    pred = pl.predict_on_robot(model, uncertainty, jp, traj, directional=True)
    return pred, true, plan_s, time.perf_counter() - start


def _methods(model, uncertainty) -> list[str]:
    """The first robot's flat-inverse prediction by both linearisations: p50, p95 and time (first call, again)."""
    jp = pl.joint_path(model, pl.reference_path("line", jr.read_description(None)))
    traj = pl.flat_motor_trajectory(model, jp)
    rows = []
    for method in METHODS:
        times = []
        for _ in range(2):
            start = time.perf_counter()
            p = pl.predict_on_robot(model, uncertainty, jp, traj, directional=True, method=method)
            times.append(time.perf_counter() - start)
        rows.append(f"| {method} | {1e6 * p.parameters_p50:.2f} | {1e6 * p.parameters_p95:.2f} | {times[0]:.1f} | "
                    f"{times[1]:.1f} |")
        print(rows[-1], flush=True)
    return rows


def _ratio(p95, true) -> float:
    """The median predicted p95 over the median true max error."""
    return float(np.median(p95) / np.median(true))


def _covered(p95, true) -> str:
    """The fraction of robots whose true max error lies at or below their predicted p95, with its 2-binomial-std
    half-width (the std of a fraction of `1/n` at least, so that an all-covered count still has an interval), as a
    table cell."""
    p95, true = np.asarray(p95), np.asarray(true)
    covered = float(np.mean(true <= p95))
    ci = 2 * float(np.sqrt(max(covered * (1 - covered), 1 / len(true)) / len(true)))
    return f"{100 * covered:.0f} % (+- {100 * ci:.0f} %, 2 binomial std)"


def _summary(stats: list[tuple[float, ...]]) -> list[str]:
    """The coverage table's rows of `stats` (per robot: p50, p95, true max error [m], plan and prediction [s])."""
    s = np.asarray(stats)
    cost = float(np.median(s[1:, 4] / s[1:, 3])) if len(s) > 1 else float(s[0, 4] / s[0, 3])
    return ["| | value | goal |", "|---|---|---|",
            f"| robots | {len(s)} | >= 50 |",
            f"| true max error <= predicted p95 | {_covered(s[:, 1], s[:, 2])} | 90-98 % |",
            f"| median p95 / median true max error | {_ratio(s[:, 1], s[:, 2]):.2f} | <= 2 |",
            f"| median true max error [um] | {1e6 * np.median(s[:, 2]):.2f} | |",
            f"| median predicted p50, p95 [um] | {1e6 * np.median(s[:, 0]):.2f}, {1e6 * np.median(s[:, 1]):.2f} | |",
            f"| prediction time / plan time (median over the robots after the first) | {cost:.2f} | <= 2 (OCP) |"]


# The independent robots (`--independent`): each robot of `../shared/independent` with calibration poses and a
# truth, calibrated from its start model, a task planned on the calibrated model by the flat inverse, the band
# predicted and the true largest error of that plan on the true robot. The Racer-7 sets (6 joints: `calibration/`,
# `poses/pK_*`) and the 7-joint arm's cases whose truth is the start model with a hidden effect a robot file holds
# (`arm7/cases`, `noise`, `tool_frame`) have `jaxrobot.Robot` truths, each checked against its `truth.json` (the
# truth's validation RMS, to 1e-6) before use, on which the plan is simulated. The arm's `calibration/` deviates
# on URDF frames, which no robot file holds: its truth is the generator's own pinocchio model
# (`arm7/make_arm7.py`, `calib_arm`), at the link angles simulated on the start model with the true gear ratios
# (the deviations move the gravity deflection by a relative ~1e-3).

SHARED = Path(__file__).resolve().parents[2] / "shared" / "independent"
ARM_TASK = (0.7, 0.2, 0.03, 0.25)
"""The arm's task: `length` [m] along y in `duration` [s] at (x, ., z) [m], flange down (the plan tests' task of
the Baxter arm, `tests/integration/test_own_robot.py`)."""


def _with(robot: jr.Robot, **fields) -> jr.Robot:
    keys = tuple(fields)
    return eqx.tree_at(lambda r: tuple(getattr(r, k) for k in keys), robot, tuple(jnp.asarray(fields[k]) for k in keys))


def _racer_truth(name: str, start: jr.Robot, truth: dict) -> jr.Robot:
    """The true Racer-7 of a set: the start model with its hidden effect (README of `independent/`)."""
    eff = truth.get("effects", {})
    if name == "calibration":
        dev = truth["deviations_from_nominal"]
        u0 = np.asarray(start.u0).copy()
        u0[3:] += np.asarray(dev["u0w"])
        return _with(start, **{f: np.asarray(getattr(start, f)) + np.asarray(dev[f]) for f in ("a", "d", "alpha")},
                     beta=np.asarray(start.beta) + np.eye(start.n_joints)[2] * dev["beta3"],
                     offset=np.asarray(start.offset) + np.asarray(dev["offset"]), u0=u0)
    if "offset_delta" in eff:
        return _with(start, offset=np.asarray(start.offset) + np.asarray(eff["offset_delta"]))
    if "stiffness_scale" in eff:  # k1 and k3 scaled: c = 1/k1 over the scale, e = k3/k1 unchanged
        return _with(start, c=np.asarray(start.c) / np.asarray(eff["stiffness_scale"]))
    if "base_xyz" in eff:
        return _with(start, base=np.asarray(start.base).copy() + np.pad(np.asarray(eff["base_xyz"])[:, None],
                                                                       ((0, 1), (3, 0))))
    if "link_scale" in eff:
        return _with(start, a=np.asarray(start.a) * eff["link_scale"], d=np.asarray(start.d) * eff["link_scale"])
    return start


def _arm_truth(start: jr.Robot, truth: dict) -> jr.Robot:
    """The true arm of a case of `arm7/cases` or `arm7/noise`/`tool_frame`: the start model with its hidden
    effect (`arm7/README.md`; the payload a point mass in the tip-link frame, which is the last link's)."""
    eff = truth.get("effects", {})
    robot = start
    if "offset_delta_rad" in eff:
        robot = _with(robot, offset=np.asarray(robot.offset) + np.asarray(eff["offset_delta_rad"]))
    if "u0_relative_delta" in eff:
        robot = _with(robot, u0=np.asarray(robot.u0) * (1 + np.asarray(eff["u0_relative_delta"])))
    if "stiffness_scale" in eff:
        robot = _with(robot, c=np.asarray(robot.c) / np.asarray(eff["stiffness_scale"]))
    if "payload_kg" in eff:
        m, lever = float(eff["payload_kg"]), np.asarray(eff["payload_position_m"], float)
        mass, com, inertia = (np.asarray(getattr(robot, f), float).copy() for f in ("mass", "com", "inertia"))
        total = mass[-1] + m
        c = (mass[-1] * com[-1] + m * lever) / total
        shift = lambda r, w: w * (r @ r * np.eye(3) - np.outer(r, r))  # noqa: E731  (parallel axes)
        inertia[-1] = inertia[-1] + shift(com[-1] - c, mass[-1]) + shift(lever - c, m)
        mass[-1], com[-1] = total, c
        robot = _with(robot, mass=mass, com=com, inertia=inertia)
    return robot


def _checked(robot: jr.Robot, val, marker, floor_um: float, label: str, mean: bool = False) -> jr.Robot:
    """`robot` after checking that it gives the validation poses the truth's RMS distance `floor_um` (`mean`: the
    mean distance)."""
    p = np.asarray(measured_pose(robot, jnp.asarray(val.motor_angles), jnp.asarray(marker))[1])
    dist = np.linalg.norm(p - val.positions, axis=-1)
    got = 1e6 * float(np.mean(dist) if mean else np.sqrt(np.mean(dist**2)))
    if abs(got - floor_um) > 1e-6 * floor_um:
        raise RuntimeError(f"{label}: the truth gives the validation poses {got:.6f} um, its truth.json "
                           f"{floor_um:.6f} um")
    return robot


def _arm_path():
    """The arm's task (`ARM_TASK`)."""
    x, z, length, duration = ARM_TASK
    t = np.arange(round(duration / 1e-3) + 1) * 1e-3
    s = t / t[-1]
    y = length * (35 * s**4 - 84 * s**5 + 70 * s**6 - 20 * s**7 - 0.5)
    p_d = np.stack([np.full_like(t, x), y, np.full_like(t, z)], -1)
    return pl.sampled_path(t, p_d, np.broadcast_to(np.diag([1.0, -1.0, -1.0]), (len(t), 3, 3)), "arm line")


def _independent_cases() -> list[dict]:
    """Every robot of `../shared/independent` with calibration poses and a truth: label, joints, start model,
    poses, measurement setup, the task, whether its gears have flanks, and the true error of a plan."""
    racer = jr.racer7_instruments()
    line = pl.reference_path("line", jr.read_description(None))
    out = []
    for d in [SHARED / "calibration", *sorted((SHARED / "poses").glob("p*"))]:
        truth = json.loads((d / "truth.json").read_text())
        start = jr.racer7() if d.name == "calibration" else jr.load_robot(d / "start.toml")
        val = read_poses(d / "val.csv")
        calibration = d.name == "calibration"  # its truth.json states the mean distance
        floor = 1e3 * truth["truth_val_mean_mm"] if calibration else truth["truth_val_rms_um"]
        true = _checked(_racer_truth(d.name, start, truth), val, racer.marker_offset, floor, d.name, calibration)
        out.append(dict(label=f"racer7 {d.name}", start=start, train=read_poses(d / "train.csv"), val=val,
                        instruments=racer, path=line, directional=True, truth=_plant_error(true, True)))
    arm = SHARED / "arm7"
    for d in [*sorted((arm / "cases").glob("a*")), *sorted((arm / "noise").glob("*")), arm / "tool_frame",
              arm / "calibration"]:
        truth = json.loads((d / "truth.json").read_text())
        start, instruments = jr.load_robot(d / "start.toml"), jr.io.read_instruments(d / "start.toml")
        if "noise_los_um" in truth:  # the laser tracker of the README, as its user states it (`_laser_tracker`)
            instruments = _laser_tracker(instruments, truth)
        val = read_poses(d / "val.csv")
        if d.name == "calibration":
            error = _pinocchio_error(start, truth)
        else:
            true = _checked(_arm_truth(start, truth), val, instruments.marker_offset, truth["floor_um"],
                            f"arm7 {d.name}")
            error = _plant_error(true, False)
        out.append(dict(label=f"arm7 {d.name}", start=start, train=read_poses(d / "train.csv"), val=val,
                        instruments=instruments, path=_arm_path(),
                        directional=False, truth=error))
    return out


def _laser_tracker(instruments: jr.Instruments, truth: dict) -> jr.Instruments:
    """`arm7/noise/anisotropic`'s measurement setup: its README's laser tracker (8 um std along the line of sight
    from the tracker at `tracker_position_m`, 35 um across; the values of its truth.json), which a user of such a
    tracker knows and states, rather than its start.toml's isotropic per-axis std of the same total variance."""
    return jr.Instruments(marker_offset=instruments.marker_offset, tracker_position=truth["tracker_position_m"],
                          tracker_noise_along=1e-6 * truth["noise_los_um"],
                          tracker_noise_across=1e-6 * truth["noise_perp_um"])


def _plant_error(truth: jr.Robot, directional: bool) -> Callable:
    """The true largest tool position error [m] of a motor trajectory along a joint path, simulated on `truth`."""
    return lambda jp, traj: float(pl.evaluate_on_plant(truth, jp, {"plan": traj},
                                                       directional=directional)["plan"].position_max)


def _pinocchio_error(start: jr.Robot, truth: dict) -> Callable:
    """The true largest error on the arm of `arm7/calibration` (the module docstring)."""
    sys.path.insert(0, str(SHARED / "arm7"))
    import make_arm7  # noqa: PLC0415  (the independent generator: numpy, scipy, pinocchio)

    x = np.asarray(list(truth["effects"].values()), float)
    arm = make_arm7.calib_arm(x)
    val = read_poses(SHARED / "arm7" / "calibration" / "val.csv")
    rms = 1e6 * float(np.sqrt(np.mean(np.sum((arm.measure(val.motor_angles) - val.positions) ** 2, -1))))
    if abs(rms - truth["floor_um"]) > 1e-6 * truth["floor_um"]:
        raise RuntimeError(f"arm7 calibration: the generator's truth gives {rms} um, truth.json {truth['floor_um']}")
    dynamics = _with(start, u0=arm.u0)

    def error(jp, traj):
        q, _ = jr.simulate(dynamics, jnp.asarray(jp.t), traj.theta, traj.thetad, traj.thetadd)
        # copied: pinocchio overwrites its data at the next call
        tip = np.array([arm.frames(qk).oMf[arm.tip].translation.copy() for qk in np.asarray(q)])
        p_d = np.asarray(pl.sample_path(jp.path, jp.t)[0])
        return float(np.max(np.linalg.norm(tip - p_d, axis=-1)))

    return error


# The alternatives (`--independent --alternatives`): the band of `predict_on_robot` beside two other readings of
# the same calibration, to show what each would give. `shrunk`: the set-aside parameters' deviations with an
# empirical-Bayes prior of their fit's shape instead of the BIC average (`_shrunk`); `field`: the unexplained residual
# as a field over the configurations regressed from the poses' residual vectors instead of its RMS added to every
# sample (`_field_p95`).

FIELD_SAMPLES = 64
"""Samples of the task at which `_field_p95` draws the residual field jointly (linear between them)."""
LENGTH_SCALES = np.geomspace(0.05, 10.0, 40)
"""[rad] the length scales among which `_field_p95` takes the one of the largest marginal likelihood."""


def _shrunk(cal, u: jr.ModelUncertainty) -> jr.ModelUncertainty:
    """`u` (the calibration's) with the set-aside parameters' true deviations `theta_A ~ N(0, g C_AA)` (Zellner's
    g-prior, `g` by its marginal likelihood: `g = max(0, W_A / a - 1)`, `W_A` the joint Wald statistic of the `a`
    set aside, the sum of their BIC steps' `dBIC_i + ln n`): given the estimate, averaged over its marginal, their
    second moment is `g C_AA` (zero where the estimates are no larger than their noise), in place of the BIC average."""
    sel = cal.selection
    if sel is None or not sel.set_aside:
        return u
    wald = float(np.sum(np.asarray(sel.delta_bic) + np.log(sel.n_residuals)))
    g = max(0.0, wald / len(sel.set_aside) - 1.0)
    cov = sel.result_covariance(g * sel.set_aside_covariance())
    return jr.ModelUncertainty(u.names, u.value, jnp.asarray(cov), u.residual_rms, u.explained_rms, u.source)


def _field_p95(cal, u: jr.ModelUncertainty, case: dict, jp, traj) -> float:
    """[m] p95 of the largest error with the unexplained residual as a field over the link angles: the residual
    vectors of the identification and validation poses regressed by a Gaussian process per axis (squared-exponential
    kernel of variance `unexplained^2 / 3`, length scale of the largest marginal likelihood among `LENGTH_SCALES`, the
    explained part `explained_rms^2 / 3` as white noise), drawn jointly at `FIELD_SAMPLES` samples of the task with
    the posterior's mean and covariance and added to the parameters' draws (`predict_on_robot`'s)."""
    theta = np.concatenate([case["train"].motor_angles, case["val"].motor_angles])
    measured = np.concatenate([case["train"].positions, case["val"].positions])
    q, x = (np.asarray(a) for a in measured_pose(cal.robot, jnp.asarray(theta),
                                                   jnp.asarray(case["instruments"].marker_offset))[:2])
    resid, signal, white = measured - x, float(u.unexplained) ** 2 / 3, float(u.explained_rms) ** 2 / 3
    n = jp.t.shape[0]
    at = np.linspace(0, n - 1, FIELD_SAMPLES).round().astype(int)
    kernel = lambda a, b, ell: signal * np.exp(-0.5 * np.sum((a[:, None] - b[None]) ** 2, -1) / ell**2)  # noqa: E731

    def evidence(ell):  # log marginal likelihood of the three axes
        chol = np.linalg.cholesky(kernel(q, q, ell) + white * np.eye(len(q)))
        return -0.5 * np.sum(np.linalg.solve(chol, resid) ** 2) - 3 * np.sum(np.log(np.diag(chol)))

    ell = max(LENGTH_SCALES, key=evidence)
    gram, cross = kernel(q, q, ell) + white * np.eye(len(q)), kernel(np.asarray(jp.q)[at], q, ell)
    mean = cross @ np.linalg.solve(gram, resid)
    w, v = np.linalg.eigh(kernel(np.asarray(jp.q)[at], np.asarray(jp.q)[at], ell) - cross @ np.linalg.solve(gram,
                                                                                                             cross.T))
    rng = np.random.default_rng(1)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    field = mean + np.einsum("ij,djk->dik", root, rng.standard_normal((DRAWS, len(at), 3)))
    between = np.stack([np.interp(np.arange(n), at, column) for column in np.eye(len(at))], -1)  # (N, samples)
    e0, jac = _linearised(cal.robot, u, jp, traj, case["directional"], "kinematic", None)
    dev = deviation_draws(u, DRAWS, 0)
    err = [np.linalg.norm(e0 + np.einsum("nij,dj->dni", jac, d) + np.einsum("ns,dsk->dnk", between, f), axis=-1)
           for d, f in zip(np.array_split(dev, DRAWS // 250), np.array_split(field, DRAWS // 250))]
    return float(np.quantile(np.concatenate(err).max(-1), 0.95))


def _independent_rows(echo: Callable[[str], None], alternatives: bool = False) -> tuple[list[tuple], list[str]]:
    """Per robot: label, joints, validation RMS and unexplained residual, p50, p95 and the true error [m] (with
    `alternatives`, then the p95 of `_shrunk` and of `_field_p95`, the latter NaN without an unexplained residual);
    and the robots left out, with why."""
    rows, left_out = [], []
    for case in _independent_cases():
        cal = calibrate(case["start"], case["train"].motor_angles, case["train"].positions,
                        validation=(case["val"].motor_angles, case["val"].positions), instruments=case["instruments"])
        if not cal.converged:
            left_out.append(f"{case['label']}: the calibration did not converge ({jr.status_name(cal.status)})")
            echo(left_out[-1])
            continue
        u = cal.uncertainty("bench_coverage --independent")
        try:
            jp = pl.joint_path(cal.robot, case["path"])
        except ValueError as e:
            left_out.append(f"{case['label']}: the task is out of its reach ({str(e).split(';')[0]})")
            echo(left_out[-1])
            continue
        traj = pl.flat_motor_trajectory(cal.robot, jp)
        pred = pl.predict_on_robot(cal.robot, u, jp, traj, directional=case["directional"])
        true = case["truth"](jp, traj)
        rows.append((case["label"], cal.robot.n_joints, float(u.residual_rms), pred.unexplained, pred.max_p50,
                     pred.max_p95, true))
        if alternatives:
            shrunk = pl.predict_on_robot(cal.robot, _shrunk(cal, u), jp, traj, directional=case["directional"])
            rows[-1] += (shrunk.max_p95, _field_p95(cal, u, case, jp, traj) if pred.unexplained > 0 else np.nan)
        echo(f"{case['label']}: p50 {1e6 * pred.max_p50:.1f} p95 {1e6 * pred.max_p95:.1f} true {1e6 * true:.1f} um"
             + "".join(f", {1e6 * a:.1f}" for a in rows[-1][7:]))
    return rows, left_out


def _bench(robots: int, ocp_robots: int, methods: bool) -> tuple[dict, dict, list[str], list[str]]:
    """The bench's robots: per plan kind ("flat", "ocp") the stats (p50, p95, true max error [m], plan and prediction
    [s]) and table rows per robot, the linearisations' rows (`methods`) and the robots left out, with why."""
    nominal, instruments = jr.racer7(), jr.racer7_instruments()
    truths = jr.bench.draw_fleet(robots, seed=0, robot=nominal)
    meas = fleet_measurements(robots, POSES + VALIDATION, range(robots), seed=0)
    rows, stats, method_rows, left_out = {"flat": [], "ocp": []}, {"flat": [], "ocp": []}, [], []
    for r in range(robots):
        truth = jax.tree.map(lambda a, r=r: a[r], truths)
        theta, pos = meas.motor_angles[r], meas.positions[r]
        cal = calibrate(nominal, theta[:POSES], pos[:POSES], validation=(theta[POSES:], pos[POSES:]),
                        instruments=instruments)
        if not cal.converged:
            left_out.append(f"robot {r}: the calibration did not converge ({jr.status_name(cal.status)})")
            print(left_out[-1], flush=True)
            continue
        u = cal.uncertainty("bench_coverage")
        if methods and not method_rows:
            method_rows = _methods(cal.robot, u)
        for kind in ("flat", "ocp")[:1 + (r < ocp_robots)]:
            pred, true, plan_s, pred_s = _plan(cal.robot, truth, u, kind)
            stats[kind].append((pred.max_p50, pred.max_p95, true, plan_s, pred_s))
            rows[kind].append(f"| {r} | {1e6 * float(u.residual_rms):.1f} | {1e6 * pred.unexplained:.1f} | "
                              f"{1e6 * pred.max_p50:.2f} | {1e6 * pred.max_p95:.2f} | {1e6 * true:.2f} | "
                              f"{'yes' if true <= pred.max_p95 else 'no'} | {plan_s:.1f} | {pred_s:.1f} |")
            print(kind, rows[kind][-1], flush=True)
    return stats, rows, method_rows, left_out


def _bench_sections(stats: dict, rows: dict, method_rows: list[str], left_out: list[str]) -> list[str]:
    """The bench's part of the results: what was measured, a section per plan kind and the linearisations'."""
    lines = [
        "## The bench", "",
        f"As-built Racer-7s (`draw_fleet(seed=0)`), each calibrated on {POSES} random poses with {VALIDATION} "
        "validation poses (tracker noise 50 um per axis, default parameter set; its `[uncertainty]` keeps the "
        "parameters BIC set aside, their covariance averaged over their models by the BIC weights); the line planned "
        "on each calibrated model and simulated on its true robot with its gears' flanks; the prediction "
        f"`predict_on_robot` (linearisation `kinematic`, {DRAWS} draws). `flat`: the flat inverse of the model (exact "
        f"on it); `ocp`: `plan_task` at nu = {NU:g} on the flanks, the first robots only (its time the plan's, "
        "compile included for the first)." + "".join(f" Left out: {line}." for line in left_out)]
    head = ["| robot | validation rms | unexplained | p50 | p95 | true | covered | plan [s] | prediction [s] |",
            "|---|---|---|---|---|---|---|---|---|"]
    for kind in ("flat", "ocp"):
        if stats[kind]:
            lines += ["", f"### `{kind}`", "", *_summary(stats[kind]), "", "Per robot (validation RMS distance, "
                      "unexplained residual, p50, p95, true max error [um]; times [s]):", "", *head, *rows[kind]]
    if method_rows:
        lines += ["", "### The linearisations", "", "The first robot's flat-inverse plan predicted by both (the "
                  "parameters' part [um]; time of the first call, compile included, and of a second [s]):", "",
                  "| method | p50 | p95 | first [s] | again [s] |", "|---|---|---|---|---|", *method_rows]
    return lines


def _independent_section(rows: list[tuple], left_out: list[str], alternatives: bool) -> list[str]:
    """The independent robots' section (the rows of `_independent_rows`; `alternatives`: their p95 and a paragraph)."""
    s = np.asarray([r[4:] for r in rows])
    covered = int(np.sum(s[:, 2] <= s[:, 1]))
    cols, bar = (" p95 shrunk | p95 field |", "---|---|") if alternatives else ("", "")
    lines = ["## Independent data", "",
             f"{len(rows)} robots of `../shared/independent` with calibration poses and a truth (6-joint Racer-7 sets, "
             "the 7-joint arm's sets; `_independent_cases`; the truth of each robot is its generator's, checked "
             "against its truth.json), each calibrated from its start model "
             "(default set, the validation poses as given; arm7 anisotropic with its README's laser tracker, "
             "`_laser_tracker`), the task (the Racer-7's line; the arm's 3 cm line in "
             "0.25 s) planned on the calibrated model by the flat inverse, the band predicted (`predict_on_robot`, "
             f"{DRAWS} draws) and the plan simulated on the true robot. True max error <= p95 on {covered} of "
             f"{len(rows)} robots: with this few robots a check that no band misses by far, not a rate "
             f"(median p95 / median true {_ratio(s[:, 1], s[:, 2]):.2f})."
             + "".join(f" Left out: {line}." for line in left_out)]
    if alternatives:
        shrunk = int(np.sum(s[:, 2] <= s[:, 3]))
        lines.append(f"\nThe alternatives (`--alternatives`): `shrunk`, the set-aside parameters with an "
                     "empirical-Bayes g-prior instead of the BIC average (`_shrunk`): true <= p95 on "
                     f"{shrunk} of {len(rows)}, median p95 / median true {_ratio(s[:, 3], s[:, 2]):.2f}; `field`, the "
                     "unexplained residual regressed over the configurations instead of its RMS (`_field_p95`; rows "
                     "with an unexplained residual).")
    return [*lines, "", "| robot | joints | validation rms | unexplained | p50 | p95 | true | covered |" + cols,
            "|---|---|---|---|---|---|---|---|" + bar,
            *[f"| {r[0]} | {r[1]} | {1e6 * r[2]:.1f} | {1e6 * r[3]:.1f} | {1e6 * r[4]:.2f} | {1e6 * r[5]:.2f} | "
              f"{1e6 * r[6]:.2f} | {'yes' if r[6] <= r[5] else 'no'} |" + "".join(f" {1e6 * a:.2f} |" for a in r[7:])
              for r in rows]]


def _pooled(flat: list[tuple[float, ...]], independent: list[tuple], left_out: list[str]) -> list[str]:
    """The goal's population in one summary: each robot of the bench once with its flat-inverse plan (`flat`: p50,
    p95, true, ...) and each independent robot (`_independent_rows`' rows), their coverage and ratio of medians,
    pooled and per population, and the ratio per joint count."""
    joints = np.array([jr.racer7().n_joints] * len(flat) + [r[1] for r in independent])
    p95 = np.array([s[1] for s in flat] + [r[5] for r in independent])
    true = np.array([s[2] for s in flat] + [r[6] for r in independent])
    parts = {"pooled": slice(None), "bench (`flat`)": slice(len(flat)), "independent": slice(len(flat), None)}
    row = lambda name, cell, goal: f"| {name} | {' | '.join(cell(k) for k in parts.values())} | {goal} |"  # noqa: E731
    per_joints = "; ".join(f"{n} joints ({np.sum(joints == n)} robots): "
                           f"{_ratio(p95[joints == n], true[joints == n]):.2f}" for n in np.unique(joints))
    return ["## The goal's population, pooled", "",
            f"The pool holds each robot measured once with the plan measured on every robot: the bench's {len(flat)} "
            "as-built robots with their flat-inverse plan (the `flat` rows; the `ocp` rows are the first of the same "
            f"robots with another plan, not counted again) and the {len(independent)} robots of the independent data "
            "(its table's rows). The coverage and the ratio are the goal's, computed as in each population's section."
            + "".join(f" Left out (no calibrated plan to check): {line}." for line in left_out), "",
            f"| | {' | '.join(parts)} | goal |", "|---|" + "---|" * len(parts) + "---|",
            row("robots", lambda k: str(len(true[k])), ">= 50"),
            row("true max error <= predicted p95", lambda k: _covered(p95[k], true[k]), "90-98 %"),
            row("median p95 / median true max error", lambda k: f"{_ratio(p95[k], true[k]):.2f}", "<= 2"),
            row("median true max error [um]", lambda k: f"{1e6 * np.median(true[k]):.2f}", ""),
            "", f"Median p95 / median true max error per joint count: {per_joints}."]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=50, help="robots of the bench whose flat-inverse plan is "
                        "predicted (0: none)")
    parser.add_argument("--ocp-robots", type=int, default=5, help="of them, the first whose OCP plan is too")
    parser.add_argument("--methods", action="store_true", help="compare the linearisations on the first robot")
    parser.add_argument("--independent", action="store_true", help="also the robots of ../shared/independent (their "
                        "own section, and with the bench's robots the pooled summary)")
    parser.add_argument("--alternatives", action="store_true",
                        help="with --independent: the p95 of the band's alternatives beside it (_shrunk, _field_p95)")
    args = parser.parse_args()
    if args.robots < 0 or args.ocp_robots < 0:
        parser.error(f"--robots and --ocp-robots must be >= 0, got {args.robots} and {args.ocp_robots}")
    if not (args.robots or args.independent):
        parser.error("nothing to measure: --robots 0 without --independent")
    if args.alternatives and not args.independent:
        parser.error("--alternatives needs --independent")
    bench = _bench(args.robots, args.ocp_robots, args.methods) if args.robots else None
    # the bench's compiled programs freed: each robot's calibration compiles its LM for the parameter set its
    # selection keeps (~850 memory maps a robot; the prediction compiles nothing per robot), and with the independent
    # robots' beside them one process exceeded the kernel's count of memory maps (XLA failed, the process crashed)
    jax.clear_caches()
    independent = (_independent_rows(lambda line: print(line, flush=True), args.alternatives) if args.independent
                   else None)
    info = _timing.run_info("none (no peer predicts a plan's error on the robot); the truth is each bench robot's own "
                            "simulation in the same run, each independent robot's its generator's (truth.json, "
                            "checked)")
    lines = ["# Predicted error bands of a plan on the robot: coverage over as-built robots of the bench and the "
             "independent data", "", _timing.header(info)]
    if bench and independent and bench[0]["flat"]:
        lines += [*_pooled(bench[0]["flat"], independent[0], bench[3] + independent[1]), ""]
    if bench:
        lines += [*_bench_sections(*bench), ""]
    if independent:
        lines += _independent_section(*independent, args.alternatives)
    OUT.write_text("\n".join(lines).rstrip("\n") + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
