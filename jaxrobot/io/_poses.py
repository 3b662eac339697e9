"""Pose files (docs/file-formats.md): `theta1_deg … thetan_deg, x_m, y_m, z_m[, qx, qy, qz, qw]
[, approach1 … approachn]`, read into `Poses` with the direction of approach of a stated convention
(`jaxrobot.measurement.APPROACHES`)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from jaxtyping import Array, Float

from ..measurement._poses import Poses, approach_ccw
from ._csv import file_joint_count, read_csv_columns, theta_columns, trajectory_run_step

POSITION_COLUMNS = ("x_m", "y_m", "z_m")
"""Required columns of a pose file after the motor angles `theta1_deg … thetan_deg` [deg]: marker position [m]."""
QUAT_COLUMNS = ("qx", "qy", "qz", "qw")
"""Optional columns: measured marker orientation as a unit quaternion (scalar last)."""


def approach_columns(n: int) -> list[str]:
    """Names of the optional per-joint direction columns of a pose file (+1 cw, -1 ccw)."""
    return [f"approach{j}" for j in range(1, n + 1)]


def write_poses(
    path: str | Path,
    motor_angles: Float[Array, "K n"] | Poses,
    positions: Float[Array, "K 3"] | None = None,
    quaternions: Float[Array, "K 4"] | None = None,
) -> None:
    """Write a pose file: `theta1_deg … thetan_deg, x_m, y_m, z_m[, qx, qy, qz, qw]`, from `Poses` (their
    measured fields) or the arrays."""
    if isinstance(motor_angles, Poses):
        if positions is not None or quaternions is not None:
            raise ValueError("motor_angles: Poses hold the measurements, found also positions or quaternions; "
                             "give either Poses or the arrays")
        poses = motor_angles
        motor_angles, positions, quaternions = poses.motor_angles, poses.positions, poses.quaternions
    theta = np.rad2deg(np.asarray(motor_angles, float))
    pos = np.asarray(positions, float)
    if theta.ndim != 2 or pos.shape != (theta.shape[0], 3):
        raise ValueError(f"write_poses: expected motor_angles (K, n) and positions (K, 3), "
                         f"found {theta.shape} and {pos.shape}")
    cols = [theta, pos]
    header = [*theta_columns(theta.shape[1]), *POSITION_COLUMNS]
    if quaternions is not None:
        cols.append(np.asarray(quaternions, float).reshape(-1, 4))
        header += list(QUAT_COLUMNS)
    table = np.concatenate(cols, 1)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[repr(float(v)) for v in row] for row in table])


def read_poses(path: str | Path, approach: str = "cw", *, reject_nan: bool = True) -> Poses:
    """Read a pose file (extra columns are ignored) with the direction of approach `ccw` of the convention
    `approach` ("cw", "order", or "column": the file's `approach1…approachn`), and `ccw_order` of its rows.

    Raises `ValueError` naming missing columns, non-numeric cells and NaN rows (`read_csv_columns`;
    `reject_nan=False`: NaN where cells are empty or `nan`, and no `ccw_order`), and for a trajectory run
    (`trajectory_run_step`), which is evidence of the motion, never a set of poses.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"pose file {path} does not exist")
    step = trajectory_run_step(path)
    if step is not None:
        raise ValueError(f"{path}: a trajectory run (t_s in equal steps of {1e3 * step:g} ms: a moving robot sampled "
                         "by the tracker), not static poses; give it as a run with its command: `jaxrobot diagnose "
                         "--runs RUN.csv --commands CMD.csv` or `jaxrobot compare --run RUN.csv --command CMD.csv`")
    n = file_joint_count(path)
    thetas = theta_columns(n)
    optional = list(QUAT_COLUMNS), approach_columns(n) if approach == "column" else []
    cols = read_csv_columns(path, [*thetas, *POSITION_COLUMNS], optional[0], reject_nan=reject_nan)
    if optional[1]:
        cols.update(read_csv_columns(path, [], optional[1]))
    theta = np.deg2rad(np.column_stack([cols[c] for c in thetas]))
    pos = np.column_stack([cols[c] for c in POSITION_COLUMNS])
    quat = np.column_stack([cols[c] for c in QUAT_COLUMNS]) if QUAT_COLUMNS[0] in cols else None
    column = np.column_stack([cols[c] for c in optional[1]]) if optional[1] and optional[1][0] in cols else None
    ccw = approach_ccw(theta, approach, column, str(path))
    if not reject_nan:
        return Poses(theta, pos, quat, ccw)
    return Poses.of(theta, pos, "column", ccw, quat)
