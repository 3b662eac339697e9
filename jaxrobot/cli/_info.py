"""`jaxrobot info`: a summary of a robot description."""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ._common import add_model_option, jsonable
from ._summary import move_tracking_error, pose_numbers

HELP = "summarise a robot: parameters, home pose, static deflection, eigenfrequencies"
EXAMPLE = "jaxrobot info --model arm.toml --as-built --out info"

POSES_DEG = {
    "home": [0, 0, 0, 0, 0, 0],
    "task orientation (docs/model.md (4.6))": [0, 0, -90, 0, 90, 0],
    "reach forward": [0, 60, -60, 0, 45, 0],
    "reach up": [30, -20, -80, 0, 30, 0],
}
"""Poses of a six-joint robot (the Racer-7's); other robots show the zero pose clipped into their
limits and the middle of their limits."""


def poses_deg(robot) -> dict[str, list[float]]:
    """The poses `jaxrobot info` evaluates [deg]."""
    if robot.n_joints == len(POSES_DEG["home"]):
        return POSES_DEG
    lo, hi = np.rad2deg(np.asarray(robot.q_min)), np.rad2deg(np.asarray(robot.q_max))
    return {"home": np.clip(0.0, lo, hi).round(3).tolist(), "mid-range": ((lo + hi) / 2).round(3).tolist()}


def configure(parser) -> None:
    add_model_option(parser)
    parser.add_argument("--as-built", action="store_true", help="the test bench's as-built robot")


def summary(robot) -> dict:
    """Numbers shown by `jaxrobot info`, its `--json` summary and `info.json`: `name` (str),
    `home_flange_position_m` (3 floats [m]) and `home_flange_rotation` (3 x 3 floats) at `q = 0`, and `poses`
    (`{pose name: {"q_deg": [float], "static_deflection_um": float, "lowest_eigenfrequency_hz": float,
    "highest_eigenfrequency_hz": float}}`): per pose of `poses_deg`, its joint coordinates [deg], the gravity
    sag of the flange [µm] and the extreme eigenfrequencies of the elastic joints with the rigid ones held
    [Hz] (None where every joint is rigid)."""
    poses = poses_deg(robot)
    numbers = pose_numbers(robot, np.deg2rad(np.asarray(list(poses.values()), float)))
    sag, freq, home = (None if a is None else np.asarray(a) for a in (numbers.sag, numbers.eigenfrequencies,
                                                                      numbers.home))
    return {
        "name": robot.name,
        "home_flange_position_m": np.asarray(home[:3, 3]),
        "home_flange_rotation": np.asarray(home[:3, :3]),
        "poses": {name: {"q_deg": v, "static_deflection_um": float(1e6 * sag[i]),
                         "lowest_eigenfrequency_hz": None if freq is None else float(freq[i, 0]),
                         "highest_eigenfrequency_hz": None if freq is None else float(freq[i, -1])}
                  for i, (name, v) in enumerate(poses.items())},
    }


def _table(robot) -> list[str]:
    rows = [f"{'joint':>5} {'a [m]':>9} {'d [m]':>9} {'alpha':>9} {'beta':>9} {'offset':>8} {'limits [deg]':>16}"
            f" {'u0':>8} {'k1 [Nm/rad]':>12} {'k3 [Nm/rad3]':>12} {'mass [kg]':>9}"]
    robot = jax.tree.map(np.asarray, robot)  # numbers on the host: no device op per table cell
    for i in range(robot.n_joints):
        lim = f"[{np.rad2deg(robot.q_min[i]):.0f}, {np.rad2deg(robot.q_max[i]):.0f}]"
        rows.append(f"{i + 1:>5} {robot.a[i]:>9.5f} {robot.d[i]:>9.5f} {np.rad2deg(robot.alpha[i]):>9.4f}"
                    f" {np.rad2deg(robot.beta[i]):>9.4f} {np.rad2deg(robot.offset[i]):>8.2f} {lim:>16}"
                    f" {robot.u0[i]:>8.4f} {robot.k1[i]:>12.4g} {robot.k3[i]:>12.4g} {robot.mass[i]:>9.2f}")
    return rows


def _report(robot, echo) -> dict:
    start = time.perf_counter()
    info = summary(robot)
    echo(f"{robot.name}  (angles in deg)")
    for row in _table(robot):
        echo(row)
    p = info["home_flange_position_m"]
    echo(f"\nhome pose (q = 0): flange at ({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m")
    rigid = np.flatnonzero(np.isinf(np.asarray(robot.k1))) + 1
    if len(rigid) == robot.n_joints:
        echo("\nall joints rigid (no [stiffness] section): no gravity sag, no elastic eigenfrequencies")
    else:
        echo(f"\n{'pose':<16} {'q [deg]':<28} {'gravity sag [um]':>16} {'f_min [Hz]':>11} {'f_max [Hz]':>11}")
        for name, row in info["poses"].items():
            echo(f"{name:<16} {str(row['q_deg']):<28} {row['static_deflection_um']:>16.1f}"
                 f" {row['lowest_eigenfrequency_hz']:>11.2f} {row['highest_eigenfrequency_hz']:>11.1f}")
        echo("(sag: flange displacement at rest when the motors are commanded theta = Xi(q) without"
             " deflection compensation; eigenfrequencies of the linearised elastic joints, motors held"
             + (f"; rigid joints held: {', '.join(map(str, rigid))})" if len(rigid) else ")"))
    echo(f"computed in {time.perf_counter() - start:.1f} s")
    return info


def run(args, echo) -> dict:
    from ..io._description import load_robot, racer7

    robot = racer7(args.as_built) if args.model is None else load_robot(args.model, args.as_built)
    info = _report(robot, echo)
    if args.out is not None:
        import json


        (args.out / "info.json").write_text(json.dumps(jsonable(info), indent=2))
    return info


def stage(out: Path, echo) -> dict:
    """Demo stage 1: the model, and the flat inverse tracking a joint move on the simulated plant.
    **Returns:** `summary` plus `flat_inverse_tracking_error_rad` (float [rad], `move_tracking_error`)."""
    from ..io._description import racer7

    robot = racer7()
    info = _report(robot, echo)
    qa = jnp.deg2rad(jnp.array([0.0, 10.0, -80.0, 0.0, 60.0, 0.0]))
    qb = jnp.deg2rad(jnp.array([40.0, 30.0, -60.0, 30.0, 30.0, 45.0]))
    duration = 1.5
    start = time.perf_counter()
    err = move_tracking_error(robot, qa, qb, duration)
    echo(f"\nflat inverse of a {duration} s joint move, simulated with RK4 (0.25 ms): max |q - q_d| = "
         f"{err:.2e} rad ({time.perf_counter() - start:.1f} s incl. compile)")
    info["flat_inverse_tracking_error_rad"] = err
    return info
