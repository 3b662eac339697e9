"""The robots of `../shared/independent` (data made by separate implementations, their READMEs state the
conventions) for `bench_coverage.py --independent`: each robot with calibration poses and a truth, calibrated from
its start model, a task planned on the calibrated model by the flat inverse, the band predicted and the true
largest error of that plan on the true robot.

The true robots: the Racer-7 sets (6 joints: `calibration/` and `poses/pK_*`) and the 7-joint arm's cases whose
truth is the start model with a hidden effect a robot file holds (`arm7/cases`, `noise`, `tool_frame`) are
`jaxrobot.Robot`s, each checked against its `truth.json` (the validation RMS of the truth, to 1e-6) before use, and
the plan is simulated on them. The arm's `calibration/` deviates on URDF frames, which no robot file holds: its
truth is the generator's own pinocchio model (`arm7/make_arm7.py`, `calib_arm`), at the link angles simulated on
the start model with the true gear ratios (the deviations move the gravity deflection by a relative ~1e-3).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
import planning as pl
from identification import calibrate
from jaxrobot.io import read_poses
from jaxrobot.measurement import measured_pose

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


def _arm_path(description: dict):
    x, z, length, duration = ARM_TASK
    t = np.arange(round(duration / 1e-3) + 1) * 1e-3
    s = t / t[-1]
    y = length * (35 * s**4 - 84 * s**5 + 70 * s**6 - 20 * s**7 - 0.5)
    p_d = np.stack([np.full_like(t, x), y, np.full_like(t, z)], -1)
    return pl.sampled_path(t, p_d, np.broadcast_to(np.diag([1.0, -1.0, -1.0]), (len(t), 3, 3)), "arm line")


def cases() -> list[dict]:
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
        val = read_poses(d / "val.csv")
        if d.name == "calibration":
            error = _pinocchio_error(start, truth)
        else:
            true = _checked(_arm_truth(start, truth), val, instruments.marker_offset, truth["floor_um"],
                            f"arm7 {d.name}")
            error = _plant_error(true, False)
        out.append(dict(label=f"arm7 {d.name}", start=start, train=read_poses(d / "train.csv"), val=val,
                        instruments=instruments, path=_arm_path(jr.read_description(d / "start.toml")),
                        directional=False, truth=error))
    return out


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
        tip = np.array([arm.frames(qk).oMf[arm.tip].translation for qk in np.asarray(q)])
        p_d = np.asarray(pl.sample_path(jp.path, jp.t)[0])
        return float(np.max(np.linalg.norm(tip - p_d, axis=-1)))

    return error


def run(echo: Callable[[str], None]) -> list[tuple]:
    """Per robot: label, joints, validation RMS and unexplained residual, p50, p95 and the true error [m]."""
    rows = []
    for case in cases():
        cal = calibrate(case["start"], case["train"].motor_angles, case["train"].positions,
                        validation=(case["val"].motor_angles, case["val"].positions), instruments=case["instruments"])
        if not cal.converged:
            echo(f"{case['label']}: calibration did not converge ({jr.status_name(cal.status)}); left out")
            continue
        u = cal.uncertainty("bench_coverage --independent")
        jp = pl.joint_path(cal.robot, case["path"])
        traj = pl.flat_motor_trajectory(cal.robot, jp)
        pred = pl.predict_on_robot(cal.robot, u, jp, traj, directional=case["directional"])
        true = case["truth"](jp, traj)
        rows.append((case["label"], cal.robot.n_joints, float(u.residual_rms), pred.unexplained, pred.max_p50,
                     pred.max_p95, true))
        echo(f"{case['label']}: p50 {1e6 * pred.max_p50:.1f} p95 {1e6 * pred.max_p95:.1f} true {1e6 * true:.1f} um")
    return rows
