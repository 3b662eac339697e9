"""Pose measurements (thesis 3.2, docs/model.md (3.6)): the motor angles of a robot at rest, the
tracker's marker positions (and orientations) there, and the direction of approach of each joint.

docs/model.md (B.1): at rest a gear uses its `cw` set unless a direction of approach is given. A set of
poses carries no such information by itself: its rows may be re-sorted, merged, or measured along paths
that do not move joint by joint. So the direction is a convention the user states (`APPROACHES`):

- `cw`: every gear at rest uses its `cw` set (the default, docs/model.md (B.1));
- `order`: the rows are in the order measured, each joint approached from the previous row
  (`approach_directions`);
- `column`: given per pose and joint (a pose file's `approach1…approachn` columns, +1 cw, -1 ccw).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._model import approach_directions

APPROACHES = ("cw", "order", "column")
"""The conventions for the direction of approach of a set of poses (`--approach`)."""


def approach_ccw(motor_angles, approach: str = "cw", column=None, name: str = "poses") -> np.ndarray:
    """Direction of approach `ccw` (K, n) of poses under the convention `approach` (see the module);
    `column` (K, n) holds the values `+1` (cw) or `-1` (ccw) per pose and joint for `approach="column"`."""
    th = np.asarray(motor_angles, float)
    if approach not in APPROACHES:
        raise ValueError(f"approach: expected one of {list(APPROACHES)}, found {approach!r}")
    if approach == "cw":
        return np.zeros(th.shape, bool)
    if approach == "order":
        return np.asarray(approach_directions(th))
    if column is None:
        columns = [f"approach{j}" for j in range(1, th.shape[-1] + 1)]
        raise ValueError(f"{name}: approach 'column' needs the columns {columns} "
                         "(+1 cw, -1 ccw per joint); the file has none; use --approach cw or order")
    col = np.asarray(column, float)
    bad = np.argwhere(~np.isin(col, (-1.0, 1.0)))
    if bad.size:
        r, j = bad[0]
        raise ValueError(f"{name}: approach{j + 1} in data row {r + 1}: expected +1 (cw) or -1 (ccw), "
                         f"found {col[r, j]:g}")
    return col < 0


@dataclasses.dataclass(frozen=True)
class Poses:
    """Tracker measurements of a robot at rest: K poses of an n-joint robot, leading axes `*b` = robots
    of a fleet, if any. The pose-file reader (`jaxrobot.io.read_poses`) and `Poses.of` give the measured
    fields; the virtual bench (`jaxrobot.bench.measure_poses`) also their noise-free truth."""

    motor_angles: np.ndarray
    """(*b, K, n) commanded motor angles at rest [rad]."""
    positions: np.ndarray
    """(*b, K, 3) measured world positions of the marker [m]."""
    quaternions: np.ndarray | None = None
    """(*b, K, 4) measured world orientations of the marker as unit quaternions (qx, qy, qz, qw); None
    without orientation measurements."""
    ccw: np.ndarray | None = None
    """(*b, K, n) bool direction of approach per pose and joint under the stated convention (`APPROACHES`);
    True: the ccw gear set. None: every gear's `cw` set (docs/model.md (B.1))."""
    ccw_order: np.ndarray | None = None
    """(*b, K, n) bool direction of approach the row order gives (`approach_directions`, per file for
    poses concatenated from several), which `diagnose` tests as a hypothesis; None: not computed."""
    link_angles: np.ndarray | None = None
    """(*b, K, n) noise-free link angles at rest under gravity [rad]; bench measurements only."""
    true_positions: np.ndarray | None = None
    """(*b, K, 3) noise-free world positions of the marker [m]; bench measurements only."""
    metadata: dict = dataclasses.field(default_factory=dict)
    """Settings of a bench session, units in the key names: `seed`, `position_noise_m`,
    `orientation_noise_rad` (None without orientation), `marker_offset_m`, `ccw` (as given) and `robot`
    (its name); empty for measured poses."""

    @classmethod
    def of(cls, motor_angles, positions, approach: str = "cw", ccw=None, quaternions=None) -> Poses:
        """Checked poses (K of them): `approach` "cw", "order" or "column" (then `ccw` (K, n) bool, e.g.
        `jaxrobot.io.read_poses`'s); `ccw_order` from the row order. Raises naming wrong shapes and NaN rows."""
        th = np.asarray(motor_angles, float)
        pos = np.asarray(positions, float)
        if th.ndim != 2 or pos.shape != (th.shape[0], 3):
            raise ValueError(f"poses: expected motor_angles (K, n) rad and positions (K, 3) m, "
                             f"found {th.shape} and {pos.shape}")
        bad = np.nonzero(~np.isfinite(np.concatenate([th, pos], 1)).all(1))[0]
        if bad.size:
            raise ValueError(f"poses: NaN/inf in rows {bad.tolist()} (0-based); remove these poses")
        quat = None if quaternions is None else np.asarray(quaternions, float)
        if quat is not None and quat.shape != (th.shape[0], 4):
            raise ValueError(f"quaternions: expected shape ({th.shape[0]}, 4), found {quat.shape}")
        if approach == "column":
            if ccw is None or np.shape(ccw) != th.shape:
                raise ValueError(f"ccw: approach 'column' needs the direction per pose and joint, shape {th.shape}, "
                                 f"found {None if ccw is None else np.shape(ccw)}")
            ccw = np.asarray(ccw, bool)
        else:
            ccw = approach_ccw(th, approach)
        return cls(th, pos, quat, ccw, np.asarray(approach_directions(th)))

    def checked(self) -> Poses:
        """These poses through `Poses.of` (their `ccw`, or `cw` where None), keeping a given `ccw_order`."""
        out = Poses.of(self.motor_angles, self.positions, "cw" if self.ccw is None else "column",
                       None if self.ccw is None else np.broadcast_to(self.ccw, np.shape(self.motor_angles)),
                       self.quaternions)
        return out if self.ccw_order is None else dataclasses.replace(out, ccw_order=np.asarray(self.ccw_order))

    @classmethod
    def concatenate(cls, parts: list[Poses]) -> Poses:
        """The poses of `parts` one after another (their measured fields; each part's `ccw_order` as computed
        for it); a field that one part lacks is None."""
        def joined(name):
            values = [getattr(p, name) for p in parts]
            return None if any(v is None for v in values) else np.concatenate(values, -2)

        return cls(*(joined(n) for n in ("motor_angles", "positions", "quaternions", "ccw", "ccw_order")))

    def __len__(self) -> int:
        return np.shape(self.motor_angles)[-2]


def pose_arrays(motor_angles, positions=None, quaternions=None, ccw=None) -> tuple:
    """`(motor_angles, positions, quaternions, ccw)` of `Poses` given as `motor_angles`, or the loose
    arrays as given; raises naming both where `Poses` come with any of the loose arrays, or where the
    arrays lack `positions`."""
    if isinstance(motor_angles, Poses):
        loose = [n for n, v in (("positions", positions), ("quaternions", quaternions), ("ccw", ccw)) if v is not None]
        if loose:
            raise ValueError(f"motor_angles: Poses hold the measurements, found also {', '.join(loose)}; "
                             "give either Poses or the arrays")
        p = motor_angles
        return p.motor_angles, p.positions, p.quaternions, p.ccw
    if positions is None:
        raise ValueError("positions: expected the (K, 3) measured marker positions [m] beside motor_angles, found "
                         "None (or give Poses as motor_angles)")
    return motor_angles, positions, quaternions, ccw
