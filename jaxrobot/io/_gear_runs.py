"""Gear-run files (docs/file-formats.md): `t_s, theta1_deg … thetan_deg, gyro_x_deg_s, gyro_y_deg_s,
gyro_z_deg_s`, one run per file, read into a `GearRun`."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..measurement._gear_run import GearRun
from ._csv import file_joint_count, read_csv_columns, theta_columns


def gear_run_columns(n: int) -> tuple[str, ...]:
    """Columns of a gear-run file of an `n`-joint robot: time [s], motor angles [deg], gyroscope [deg/s]."""
    return ("t_s", *theta_columns(n), "gyro_x_deg_s", "gyro_y_deg_s", "gyro_z_deg_s")


def write_gear_run(path: str | Path, t: np.ndarray | GearRun, theta: np.ndarray | None = None,
                   gyro: np.ndarray | None = None) -> None:
    """Write one run: a single-run `GearRun` (its measured fields), or `t` (N,) s, `theta` (N, n) rad,
    `gyro` (N, 3) rad/s; the file holds degrees as its column names say."""
    if isinstance(t, GearRun):
        if theta is not None or gyro is not None:
            raise ValueError("t: a GearRun holds the run, found also theta or gyro; give either a GearRun or "
                             "the arrays")
        t, theta, gyro = t.t, t.theta, t.gyro
    t, theta, gyro = np.asarray(t, float), np.asarray(theta, float), np.asarray(gyro, float)
    n = t.shape[0] if t.ndim == 1 else -1
    if t.ndim != 1 or theta.ndim != 2 or theta.shape[0] != n or gyro.shape != (n, 3):
        raise ValueError(f"write_gear_run: expected t (N,), theta (N, n), gyro (N, 3), found "
                         f"{t.shape}, {theta.shape}, {gyro.shape}")
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(gear_run_columns(theta.shape[1]))
        th, gy = np.rad2deg(theta), np.rad2deg(gyro)
        for k in range(n):
            w.writerow([f"{t[k]:.6f}", *(f"{x:.12g}" for x in th[k]), *(f"{x:.9g}" for x in gy[k])])


def read_gear_run(path: str | Path) -> GearRun:
    """Read one gear-run file (extra columns are ignored): `GearRun` with `t` (N,) s, `theta` (N, n) rad,
    `gyro` (N, 3) rad/s. Empty cells and `nan` come back as NaN (the processing rejects them with the row
    named)."""
    columns = gear_run_columns(file_joint_count(path))
    cols = read_csv_columns(path, list(columns), reject_nan=False, min_rows=2)
    data = np.column_stack([cols[c] for c in columns])
    return GearRun(data[:, 0], np.deg2rad(data[:, 1:-3]), np.deg2rad(data[:, -3:]))
