"""The CSV measurement files (docs/file-formats.md): motor-angle columns, the joint count of a file, a
checked column reader, and the test that tells a trajectory run from static poses."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


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
