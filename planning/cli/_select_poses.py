"""`jaxrobot select-poses --task line --count K`: calibration poses designed for one task (the least predicted path
error of the task, `identification.calibration.task_poses`), beside DETMAX's (the O1 index of the whole parameter
set) at the same count, with the predicted largest path error of the task after a calibration on each."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.cli import add_model_option
from jaxrobot.measurement import marker_pose

from .._evaluation import flat_motor_trajectory
from .._ik import joint_path
from .._prediction import RobotPrediction, predict_on_robot, task_weight
from ._plan import task_path

HELP = "choose calibration poses that minimise a task's predicted path error, compared with DETMAX at the same count"
EXAMPLE = "jaxrobot select-poses --task line --count 15 --out poses.csv"
OUT_FILE = ("the pose file to write (theta1_deg..thetan_deg and x_m, y_m, z_m: the marker where the model expects "
            "it; measure there and replace x_m, y_m, z_m by the tracker's positions for `jaxrobot calibrate`)")


def configure(parser) -> None:
    parser.add_argument("--task", default="line", help="'line' (default), 'spiral' or FILE.csv (as `jaxrobot plan`)")
    parser.add_argument("--count", type=int, default=15, help="calibration poses to choose (default 15)")
    parser.add_argument("--setup", type=Path, default=None, metavar="FILE",
                        help="measurement setup with the tracker's marker and noise ([sensors]; default: the "
                             "model file's, without --model the embedded Racer-7 bench's)")
    add_model_option(parser, "robot model TOML whose parameters the calibration identifies (default: the "
                             "embedded Racer-7)")
    parser.add_argument("--pool", type=int, default=4000, help="random feasible candidate poses (default 4000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the candidate pool and of DETMAX (default 0)")
    parser.add_argument("--refine-steps", type=int, default=100, metavar="N",
                        help="steps of the continuous refinement of the designed poses off the pool (default 100; "
                             "0: keep the pool's poses)")


def _prediction(robot, params, blocks, sigma, jp, traj) -> RobotPrediction | None:
    """The task's predicted error after a least-squares calibration on the poses of `blocks` (None where they do
    not identify every parameter)."""
    from identification.calibration import pose_covariance

    try:
        cov = pose_covariance(blocks, sigma)
    except ValueError:
        return None
    u = jr.ModelUncertainty(params.entries, params.get(robot), jnp.asarray(cov), jnp.asarray(0.0), jnp.asarray(0.0),
                            "select-poses")
    return predict_on_robot(robot, u, jp, traj)


def run(args, echo) -> dict:
    """`jaxrobot select-poses`; the `--json` summary is `{"task": str, "count": int, "parameters": [str],
    "designed", "detmax": {"p50_um", "p95_um": float} or None, "refined": int}`: the predicted largest path error
    [um] of the task (its motor trajectory the model's flat inverse) after a least-squares calibration of
    `parameters` on the designed and on DETMAX's poses with the setup's tracker noise (None: the poses do not
    identify every parameter), the accepted steps of the designed poses' refinement off the pool, and `"out"` (str
    or None), the pose file written."""
    from identification.calibration import (
        ParameterMap,
        default_parameters,
        detmax,
        pose_jacobians,
        random_feasible_poses,
        task_poses,
    )

    if args.count < 1 or args.pool <= args.count:
        raise ValueError(f"--count, --pool: expected 1 <= count < pool, found {args.count} and {args.pool}")
    if args.refine_steps < 0:
        raise ValueError(f"--refine-steps: expected an integer >= 0, found {args.refine_steps}")
    desc = jr.read_description(args.model)
    robot = jr.robot_from_description(desc)
    marker, sigma = jr.io.read_instruments(args.setup if args.setup is not None else args.model).require(
        "marker_offset", "tracker_noise", by="select-poses")
    path = task_path(args.task, desc)
    params = ParameterMap(default_parameters(robot, marker=marker))
    echo(f"{path.name}: the task's sensitivity to the {len(params)} parameters (flat inverse on {robot.name})")
    jp = joint_path(robot, path)
    traj = flat_motor_trajectory(robot, jp)
    weight = task_weight(robot, params.entries, jp, traj)
    echo(f"pool of {args.pool} feasible poses; designing {args.count} poses and DETMAX's {args.count}")
    q_pool = random_feasible_poses(robot, args.pool, args.seed, marker=marker)
    pool = (q_pool, pose_jacobians(robot, params, q_pool, marker))
    design = task_poses(robot, params, weight, args.count, marker=marker, sigma=float(sigma), pool=pool,
                        refine_steps=args.refine_steps)
    echo(f"  designed: {design.iterations} exchanges on the pool, {design.refined} refinement steps off it")
    o1 = detmax(robot, params, args.count, args.seed, marker=marker, pool=pool)
    rows = {}
    for name, q in (("designed", design.q), ("detmax", o1.q)):
        p = _prediction(robot, params, pose_jacobians(robot, params, q, marker), float(sigma), jp, traj)
        rows[name] = None if p is None else {"p50_um": 1e6 * p.parameters_p50, "p95_um": 1e6 * p.parameters_p95}
        echo(f"  {name:8s} poses: predicted largest path error of {path.name} "
             + ("p50 {p50_um:.1f} um, p95 {p95_um:.1f} um".format(**rows[name]) if p is not None
                else "none (the poses do not identify every parameter)"))
    if args.out is not None:
        jr.io.write_poses(args.out, design.motor_angles, np.asarray(marker_pose(robot, design.q, marker)[0]))
        echo(f"  wrote {args.out}")
    return {"task": path.name, "count": args.count, "parameters": list(params.names), **rows, "refined": design.refined,
            "out": None if args.out is None else str(args.out)}
