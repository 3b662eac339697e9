"""Virtual test bench for kinematic calibration: pose measurements with an optical tracker
(thesis 3.2, docs/model.md (3.6)).

The as-built robot rests at commanded motor angles `theta`; its link angles are
`Xi^{-1}(theta)` plus the gravity deflection (`jaxrobot.measurement`, thesis 3.2.3); the tracker
reports the world position of a marker body fixed in the tool frame (the flange frame for the
identity tool) with Gaussian noise, and optionally its orientation as a unit quaternion.
Also: random fleets of as-built robots.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._instruments import Instruments
from .._program_cache import cached_program
from .._robot import Robot
from .._rotations import rotation_to_quaternion, rotvec_to_rotation
from .._status import require_successful
from ..io._description import racer7, read_as_built
from ..io._instruments import bench_instruments
from ..measurement._model import measured_pose
from ..measurement._poses import Poses

# Parameters of the Racer-7 that deviate in the as-built robot (the entries of thesis Table 3.8);
# `draw_fleet` puts random deviations on them (on all but the last joint for other robots).
_FLEET_MASK = {
    "a": np.array([1, 1, 1, 1, 1, 0], bool),
    "d": np.array([0, 1, 0, 1, 0, 0], bool),
    "alpha": np.array([1, 1, 1, 1, 1, 0], bool),
    "beta": np.array([0, 0, 1, 0, 0, 0], bool),
}


_measure = cached_program(filter=True)(measured_pose)


def _fleet_axes(robot: Robot) -> tuple[int, ...]:
    return tuple(np.shape(robot.a)[:-1])


def measure_poses(
    truth: Robot,
    motor_angles: Float[Array, "*b K n"],
    *,
    seed: int = 0,
    instruments: Instruments | None = None,
    orientation: bool = False,
    ccw: bool | Bool[Array, "*b K n"] = False,
) -> Poses:
    """Tracker measurements of `truth` resting at `motor_angles` (thesis 3.2.3, docs/model.md (3.6)).

    **Arguments:**
    - `truth`: the as-built robot, or a fleet with leading axes `*b`.
    - `motor_angles`: commanded motor angles [rad], (K, n) (shared by the fleet) or (*b, K, n).
    - `seed`: seed of the Gaussian noise.
    - `instruments`: the tracker's marker offset, isotropic position noise and orientation noise
      (`marker_offset`, `tracker_noise`, `tracker_orientation_noise`); required for a robot other than the
      embedded Racer-7, whose default is its bench's (`jaxrobot.racer7_instruments()`).
    - `orientation`: also report the marker orientation as a quaternion, rotated by a random rotation vector with
      the std `tracker_orientation_noise` per axis [rad].
    - `ccw`: gear set of the last approach direction (default `cw`, docs/model.md (B.1)).

    **Returns:** `Poses` (plain numpy arrays; `ccw` broadcast to the poses, None for the default `cw`) with
    their noise-free truth and metadata. Raises the status message where the rest fixed point failed
    (`jaxrobot.measurement.rest_link_angles`; never for the default robot).
    """
    instruments = bench_instruments(truth, instruments, by="measure_poses")
    marker, sigma = instruments.require("marker_offset", "tracker_noise", by="measure_poses")
    orientation_noise = instruments.tracker_orientation_noise
    theta = jnp.asarray(motor_angles, float)
    fleet = _fleet_axes(truth)
    n = truth.n_joints
    if theta.ndim < 2 or theta.shape[-1] != n:
        raise ValueError(f"motor_angles: expected shape (K, {n}) or (*fleet, K, {n}) in rad, found {theta.shape}")
    if sigma < 0 or orientation_noise < 0:
        raise ValueError(f"noise: expected std >= 0, found position {sigma}, orientation {orientation_noise}")
    theta = jnp.broadcast_to(theta, fleet + theta.shape[-2:])
    # the robot's fleet axes broadcast against the pose axis K
    robot = jax.tree.map(lambda x: jnp.expand_dims(x, len(fleet)), truth) if fleet else truth
    q, p, r, result = _measure(robot, theta, jnp.asarray(marker), ccw)
    require_successful(result, "measure_poses: rest pose of the measured robot")
    key_p, key_r = jax.random.split(jax.random.PRNGKey(seed))
    noisy = p + sigma * jax.random.normal(key_p, p.shape)
    quat = None
    if orientation:
        err = orientation_noise * jax.random.normal(key_r, p.shape)
        quat = np.asarray(rotation_to_quaternion(r @ rotvec_to_rotation(err)))
    meta = {"seed": seed, "position_noise_m": sigma,
            "orientation_noise_rad": orientation_noise if orientation else None,
            "marker_offset_m": marker.tolist(), "ccw": np.asarray(ccw).tolist(),
            "robot": truth.name}
    given = None if np.ndim(ccw) == 0 and not ccw else np.broadcast_to(np.asarray(ccw, bool), theta.shape)
    return Poses(np.asarray(theta), np.asarray(noisy), quat, given,
                 link_angles=np.asarray(q), true_positions=np.asarray(p), metadata=meta)


def _table_3_8_stds() -> tuple[float, float, float]:
    """The rms of the as-built deviations of the Racer-7 (thesis Table 3.8, `[as_built]` of the embedded
    description): of the lengths [m], of the angles [rad] and of the relative errors of the wrist ratios."""
    dev = read_as_built(None)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    entries = lambda *keys: np.concatenate([dev[f"delta_{k}"][_FLEET_MASK[k]] for k in keys])  # noqa: E731
    return rms(entries("a", "d")), rms(entries("alpha", "beta")), rms(dev["u0_relative"][3:])


def draw_fleet(
    n: int,
    seed: int = 0,
    robot: Robot | None = None,
    *,
    length_std: float | None = None,
    angle_std: float | None = None,
    ratio_std: float | None = None,
    offset_std: float = 0.0,
) -> Robot:
    """`n` random as-built robots: `robot` (default nominal Racer-7) plus Gaussian deviations.

    Deviations go on the parameters of thesis Table 3.8 (a1..a5, d2, d4, alpha1..alpha5, beta3,
    u0 of gears 4-6) for a six-joint robot, on a, d, alpha, beta of all joints but the last and
    on every u0 for other robots, optionally also on the joint offsets. Default stds, for any robot: the rms of
    the Table 3.8 entries (`[as_built]` of the embedded Racer-7, `jaxrobot.io.read_as_built(None)`): lengths,
    angles, and the relative wrist-ratio errors. Returns the
    robot pytree with a leading axis `n`.
    """
    robot = racer7() if robot is None else robot
    ls, ang, rel = _table_3_8_stds()
    joints = robot.n_joints
    six = joints == len(_FLEET_MASK["a"])
    mask = {k: m if six else np.arange(joints) < joints - 1 for k, m in _FLEET_MASK.items()}
    ratio_mask = np.arange(joints) >= 3 if six else np.ones(joints, bool)
    length_std = ls if length_std is None else length_std
    angle_std = ang if angle_std is None else angle_std
    ratio_std = rel if ratio_std is None else ratio_std
    if n < 1:
        raise ValueError(f"n: expected a fleet size >= 1, found {n}")
    rng = np.random.default_rng(seed)
    fleet = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), robot)
    upd = {}
    for k, std in (("a", length_std), ("d", length_std), ("alpha", angle_std), ("beta", angle_std)):
        upd[k] = np.asarray(getattr(robot, k)) + std * rng.standard_normal((n, joints)) * mask[k]
    upd["u0"] = np.asarray(robot.u0) * (1.0 + ratio_std * rng.standard_normal((n, joints)) * ratio_mask)
    upd["offset"] = np.asarray(robot.offset) + offset_std * rng.standard_normal((n, joints))
    names = tuple(upd)
    return eqx.tree_at(lambda r: tuple(getattr(r, k) for k in names), fleet,
                       tuple(jnp.asarray(upd[k]) for k in names))
