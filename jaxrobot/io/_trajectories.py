"""Trajectory files (docs/file-formats.md): trajectory runs (the tracker's marker positions along a
commanded motion) and the motor commands that `jaxrobot plan --save-trajectory` writes."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ._csv import NOT_CONVERGED, file_joint_count, read_csv_columns, theta_columns


def write_trajectory_csv(path: str | Path, t, theta, positions) -> None:
    """Write a trajectory run: `t_s, theta1_deg … thetan_deg, x_m, y_m, z_m`."""
    data = np.column_stack([np.asarray(t), np.rad2deg(np.asarray(theta)), np.asarray(positions)])
    columns = ["t_s", *theta_columns(np.shape(theta)[-1]), "x_m", "y_m", "z_m"]
    np.savetxt(path, data, delimiter=",", header=",".join(columns), comments="", fmt="%.12g")


def command_columns(n: int) -> list[str]:
    """Columns of a command file of an `n`-joint robot: `t_s`, motor angles [deg], rates [deg/s] and
    accelerations [deg/s^2]."""
    joints = range(1, n + 1)
    return (["t_s", *theta_columns(n)] + [f"thetad{i}_deg_s" for i in joints]
            + [f"thetadd{i}_deg_s2" for i in joints])


def write_command_csv(path: str | Path, t, theta, thetad, thetadd, failed: str | None = None) -> None:
    """Write a motor command (the trajectory `jaxrobot plan --save-trajectory` saves): `command_columns`;
    `failed` (the status of a solve that did not converge) puts `NOT_CONVERGED` and it in a first line, which
    the readers refuse."""
    header = ",".join(command_columns(np.shape(theta)[-1]))
    header = header if failed is None else f"{NOT_CONVERGED}: {failed}\n" + header
    data = np.column_stack([np.asarray(t)] + [np.degrees(np.asarray(a)) for a in (theta, thetad, thetadd)])
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.12g")


def read_command_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Read a motor command: times [s] (N,) on a uniform grid, motor angles [rad], rates [rad/s] and
    accelerations [rad/s^2] (N, n). Raises naming the file for a trajectory run (no rate columns), a
    non-uniform time step or fewer than 2 samples."""
    n = file_joint_count(path)
    columns = command_columns(n)
    with Path(path).open(newline="") as f:
        header = {h.strip() for h in next(csv.reader(f), [])}
    if {"x_m", "y_m", "z_m"} <= header and not set(columns) <= header:
        raise ValueError(f"{path}: a trajectory run (columns x_m, y_m, z_m: the tracker's positions), not a motor "
                         f"command; a command has the columns {columns[:2] + ['…'] + columns[-1:]}, as "
                         "`jaxrobot plan --save-trajectory` writes them")
    cols = read_csv_columns(path, columns, min_rows=2)
    t = cols["t_s"]
    step = np.diff(t)
    if np.any(step <= 0) or np.ptp(step) > 1e-9 * np.max(np.abs(t)) + 1e-12:
        raise ValueError(f"{path}: t_s must increase in equal steps (the command is a sampled trajectory); found "
                         f"steps from {step.min():g} to {step.max():g} s")
    theta, thetad, thetadd = (np.deg2rad(np.column_stack([cols[c] for c in columns[1 + k * n:1 + (k + 1) * n]]))
                              for k in range(3))
    return t, theta, thetad, thetadd


def read_trajectory_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a trajectory run: times [s] (N,), motor angles [rad] (N, n), positions [m] (N, 3)."""
    thetas = theta_columns(file_joint_count(path))
    cols = read_csv_columns(path, ["t_s", *thetas, "x_m", "y_m", "z_m"])
    t = cols["t_s"]
    if np.any(np.diff(t) <= 0):
        line = int(np.nonzero(np.diff(t) <= 0)[0][0]) + 3
        raise ValueError(f"{path}: t_s must increase strictly; it does not at line {line}")
    theta = np.deg2rad(np.column_stack([cols[c] for c in thetas]))
    return t, theta, np.column_stack([cols["x_m"], cols["y_m"], cols["z_m"]])
