"""Pose files for identification: the direction of approach as an explicit convention.

SPEC.md: at rest a gear uses its `cw` set unless a direction of approach is given. A pose file
carries no such information by itself: its rows may be re-sorted, merged, or measured along paths
that do not move joint by joint. So the direction is a convention the user states (`approach`):

- `cw`: every gear at rest uses its `cw` set (SPEC.md's default);
- `order`: the rows are in the order measured, each joint approached from the previous row
  (`jaxrobot.approach_directions`);
- `column`: the file gives it, one column `approach1…approachn` per joint, +1 (cw) or -1 (ccw).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import jaxrobot as jr

APPROACHES = ("cw", "order", "column")
"""The conventions for the direction of approach of a pose file (`--approach`)."""


def approach_columns(n: int) -> list[str]:
    """Names of the optional per-joint direction columns of a pose file."""
    return [f"approach{j}" for j in range(1, n + 1)]


def approach_ccw(motor_angles, approach: str = "cw", column=None, name: str = "poses") -> np.ndarray:
    """Direction of approach `ccw` (K, n) of poses under the convention `approach` (see the module);
    `column` (K, n) holds the file's `approach1…n` values (+1 cw, -1 ccw) for `approach="column"`."""
    th = np.asarray(motor_angles, float)
    if approach not in APPROACHES:
        raise ValueError(f"approach: expected one of {list(APPROACHES)}, found {approach!r}")
    if approach == "cw":
        return np.zeros(th.shape, bool)
    if approach == "order":
        return np.asarray(jr.approach_directions(th))
    if column is None:
        raise ValueError(f"{name}: approach 'column' needs the columns {approach_columns(th.shape[-1])} "
                         "(+1 cw, -1 ccw per joint); the file has none; use --approach cw or order")
    col = np.asarray(column, float)
    bad = np.argwhere(~np.isin(col, (-1.0, 1.0)))
    if bad.size:
        r, j = bad[0]
        raise ValueError(f"{name}: approach{j + 1} in data row {r + 1}: expected +1 (cw) or -1 (ccw), "
                         f"found {col[r, j]:g}")
    return col < 0


def read_poses(path: str | Path, approach: str = "cw") -> dict:
    """Read a pose file (SPEC.md) with the direction of approach of the convention `approach`.

    **Returns:** `jaxrobot.read_pose_csv`'s `motor_angles` (K, n) rad, `positions` (K, 3) m and
    `quaternions`, plus `ccw` (K, n) bool.
    """
    from jaxrobot._bench_trajectory import read_csv_columns

    data = jr.read_pose_csv(path)
    n = data["motor_angles"].shape[1]
    column = None
    if approach == "column":
        cols = read_csv_columns(path, [], approach_columns(n))
        column = np.column_stack([cols[c] for c in approach_columns(n)]) if cols else None
    return dict(data, ccw=approach_ccw(data["motor_angles"], approach, column, str(path)))


def add_approach_option(parser) -> None:
    """`--approach {cw,order,column}` of every command that reads pose files."""
    parser.add_argument("--approach", choices=APPROACHES, default="cw",
                        help="direction of approach at rest: cw = every gear's cw set (SPEC.md, default); "
                             "order = from the row order (rows in the order measured); column = the file's "
                             "approach1..approachn columns (+1 cw, -1 ccw)")
