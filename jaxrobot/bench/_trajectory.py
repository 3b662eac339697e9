"""Virtual test bench, trajectory runs (docs/file-formats.md): the motor follows a commanded `theta(t)`
exactly, the elastic model of the as-built robot is integrated finely, and the optical tracker
reports the marker position along the path with Gaussian noise. Also the command files that `jaxrobot plan
--save-trajectory` writes (`write_command_csv`, `read_command_csv`)."""

from __future__ import annotations

import csv
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .._kinematics import point_position
from .._robot import Robot
from .._simulate import simulate


def theta_columns(n: int) -> list[str]:
    """Motor-angle columns `theta1_deg ... thetan_deg` [deg] of the bench files of an `n`-joint robot."""
    return [f"theta{i}_deg" for i in range(1, n + 1)]


def file_joint_count(path: str | Path) -> int:
    """Joints of a bench file: its consecutive columns `theta1_deg, theta2_deg, ...` (1 if it has none,
    so that a reader names `theta1_deg` as missing)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    with path.open(newline="") as f:
        header = {h.strip() for h in next(csv.reader(f), [])}
    n = 0
    while f"theta{n + 1}_deg" in header:
        n += 1
    return max(n, 1)


def trajectory_run(
    robot: Robot,
    key: PRNGKeyArray,
    t: Float[Array, " N"],
    theta: Float[Array, "N n"],
    thetad: Float[Array, "N n"],
    thetadd: Float[Array, "N n"],
    marker: Float[Array, "3"],
    noise_m: float,
    substeps: int = 10,
) -> tuple[Float[Array, "N 3"], Float[Array, "N n"]]:
    """Tracker positions (N, 3) [m] of the marker and the true link angles (N, n) of `robot`
    following the commanded motor trajectory (direction-dependent gear sets, rest at start)."""
    q, _ = simulate(robot, t, theta, thetad, thetadd, substeps=substeps, directional=True)
    p = point_position(robot, q, jnp.asarray(marker))
    return p + noise_m * jax.random.normal(key, p.shape), q


def write_trajectory_csv(path: str | Path, t, theta, positions) -> None:
    """Write a trajectory run: `t_s, theta1_deg … thetan_deg, x_m, y_m, z_m`."""
    data = np.column_stack([np.asarray(t), np.rad2deg(np.asarray(theta)), np.asarray(positions)])
    columns = ["t_s", *theta_columns(np.shape(theta)[-1]), "x_m", "y_m", "z_m"]
    np.savetxt(path, data, delimiter=",", header=",".join(columns), comments="", fmt="%.12g")


NOT_CONVERGED = "# NOT CONVERGED"
"""First line of a result file written from a solve that did not converge (`plan --save-failed`);
`read_csv_columns` refuses such a file."""


def read_csv_columns(
    path: str | Path, required: list[str], optional: list[str] = (), *, reject_nan: bool = True,
    min_rows: int = 1,
) -> dict[str, np.ndarray]:
    """Read a measurement CSV with a header (the formats of docs/file-formats.md; extra columns are ignored).

    Returns the `required` columns, and the `optional` ones if the file has all of them. Empty
    cells and `nan` are NaN; with `reject_nan` rows holding them are rejected. Raises naming the
    file, the missing columns, a non-numeric cell (line and column) or the NaN lines (the header
    is line 1, so data row k is line k + 1)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if rows and rows[0] and rows[0][0].startswith(NOT_CONVERGED):
        raise ValueError(f"{path}: written from a solve that did not converge ({','.join(rows[0])}); "
                         "not a result")
    header = [h.strip() for h in rows[0]] if rows else []
    missing = [c for c in required if c not in header]
    if missing:
        raise ValueError(f"{path}: missing columns {missing}; expected {list(required)}"
                         f"{f' (optional {list(optional)})' if optional else ''}, found {header}")
    partial = [c for c in optional if c in header]
    if partial and len(partial) < len(optional):
        raise ValueError(f"{path}: the optional columns {list(optional)} come together, found only {partial}")
    wanted = list(required) + (list(optional) if partial else [])
    idx = [header.index(c) for c in wanted]
    data = np.full((len(rows) - 1, len(wanted)), np.nan)
    for r, row in enumerate(rows[1:]):
        for j, i in enumerate(idx):
            cell = row[i].strip() if i < len(row) else ""
            if cell:
                try:
                    data[r, j] = float(cell)
                except ValueError:
                    raise ValueError(f"{path}: line {r + 2}, column {wanted[j]}: expected a number, found "
                                     f"{cell!r}") from None
    if data.shape[0] < min_rows:
        raise ValueError(f"{path}: expected at least {min_rows} data row(s), found {data.shape[0]}")
    bad = np.nonzero(~np.all(np.isfinite(data), axis=1))[0]
    if reject_nan and bad.size:
        lines = (bad + 2).tolist()
        raise ValueError(f"{path}: NaN or empty cells in line(s) {lines[:20]}{' …' if len(lines) > 20 else ''} "
                         f"(data row k is line k + 1); remove or re-measure these rows")
    return {c: data[:, i] for i, c in enumerate(wanted)}


RUN_MAX_STEP_S = 0.1
"""A file whose `t_s` advances in equal steps shorter than this [s] is a trajectory run, not static poses: a pose
is measured with the robot at rest, which it does not reach again within this time after a move."""


def trajectory_run_step(path: str | Path) -> float | None:
    """The sample time [s] of `path` if it is a trajectory run (`t_s` in equal steps below `RUN_MAX_STEP_S`,
    at least 3 rows), else None."""
    t = read_csv_columns(path, [], ["t_s"], reject_nan=False).get("t_s")
    if t is None or len(t) < 3 or not np.all(np.isfinite(t)):
        return None
    step = np.diff(t)
    uniform = np.all(step > 0) and np.ptp(step) <= 1e-6 * np.mean(step)
    return float(np.mean(step)) if uniform and np.mean(step) < RUN_MAX_STEP_S else None


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
