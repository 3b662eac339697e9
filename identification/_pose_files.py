"""Pose files for identification: the direction of approach as an explicit convention.

docs/model.md (B.1): at rest a gear uses its `cw` set unless a direction of approach is given. A pose file
carries no such information by itself: its rows may be re-sorted, merged, or measured along paths
that do not move joint by joint. So the direction is a convention the user states (`approach`):

- `cw`: every gear at rest uses its `cw` set (the default, docs/model.md (B.1));
- `order`: the rows are in the order measured, each joint approached from the previous row
  (`jaxrobot.approach_directions`);
- `column`: the file gives it, one column `approach1…approachn` per joint, +1 (cw) or -1 (ccw).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.bench import PoseFile, read_csv_columns, read_pose_csv
from jaxrobot.measurement import approach_directions, marker_pose

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
        return np.asarray(approach_directions(th))
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


def read_poses(path: str | Path, approach: str = "cw", *, reject_nan: bool = True) -> PoseFile:
    """Read a pose file (docs/file-formats.md) with the direction of approach of the convention
    `approach`: `jaxrobot.bench.read_pose_csv`'s `PoseFile` (`reject_nan` as there) with its `ccw` (K, n) set."""
    data = read_pose_csv(path, reject_nan=reject_nan)
    n = data.motor_angles.shape[1]
    column = None
    if approach == "column":
        cols = read_csv_columns(path, [], approach_columns(n))
        column = np.column_stack([cols[c] for c in approach_columns(n)]) if cols else None
    return dataclasses.replace(data, ccw=approach_ccw(data.motor_angles, approach, column, str(path)))


GROSS_ERROR_M = 0.05
"""Model and measured marker positions farther apart (RMS) than this mean wrong units or columns:
kinematic deviations of a robot are millimetres, not centimetres."""
ANGLE_MISTAKES = {
    "link angles in the motor columns (theta_deg is the motor side: link angle times u0)": "link",
    "radians in the _deg columns": 180.0 / np.pi,
    "degrees x1000 in the _deg columns": 1e-3,
}
"""Common mistakes in the motor-angle columns: factor to the intended motor angles ("link": u0)."""


@jax.jit
def _marker_positions(robot: jr.Robot, q, marker):
    """Marker positions (K, 3) [m] at the link angles `q` (K, n), one compiled program per shape."""
    return marker_pose(robot, q, marker)[0]


def check_pose_units(robot: jr.Robot, motor_angles, positions, marker, name: str = "poses") -> None:
    """Reject pose data whose magnitudes betray a unit mistake, before any fit: positions beyond
    the robot's reach (millimetres in the `_m` columns), and motor angles that put the model's
    marker far (> `GROSS_ERROR_M` RMS) from the measured one where a common mistake
    (`ANGLE_MISTAKES`) would put it close; `marker` is in the tool frame, as in the measurement model
    (`jaxrobot.measurement.marker_pose`). Raises `ValueError` naming the likely mistake."""
    th = np.asarray(motor_angles, float)
    pos = np.asarray(positions, float)
    marker = np.asarray(marker, float)
    base = np.asarray(robot.base)[:3, 3]
    reach = float(np.sum(np.abs(np.asarray(robot.a))) + np.sum(np.abs(np.asarray(robot.d))) + np.linalg.norm(marker)
                  + np.linalg.norm(np.asarray(robot.tool)[:3, 3]))
    far = float(np.max(np.linalg.norm(pos - base, axis=-1)))
    if far > 2.0 * reach:
        mm = " (millimetres in the _m columns?)" if far / 1e3 <= 2.0 * reach else ""
        raise ValueError(f"{name}: marker positions up to {far:.4g} from the base, but the robot reaches "
                         f"{reach:.3g} m{mm}; positions x_m, y_m, z_m must be metres")
    u0 = np.asarray(robot.u0, float)

    def rms(theta):
        p = np.asarray(_marker_positions(robot, jnp.asarray(theta / u0), jnp.asarray(marker)))
        return float(np.sqrt(np.mean(np.sum((p - pos) ** 2, -1))))

    err = rms(th)
    if not err > GROSS_ERROR_M:
        return
    fits = [(text, e) for text, f in ANGLE_MISTAKES.items()
            if (e := rms(th * (u0 if isinstance(f, str) else f))) <= GROSS_ERROR_M]
    if fits:
        text, e = min(fits, key=lambda t: t[1])
        raise ValueError(f"{name}: the model puts the marker {1e3 * err:.1f} mm (RMS) from the measured positions, "
                         f"{1e3 * e:.2f} mm if the file has {text}; expected motor-side angles in degrees")
    raise ValueError(f"{name}: the model puts the marker {1e3 * err:.1f} mm (RMS) from the measured positions "
                     f"(more than {1e3 * GROSS_ERROR_M:.0f} mm); check the units (motor-side degrees, metres), the "
                     "marker offset and the robot file")
