"""The gyroscope on a moving link (thesis 3.1.1, eq. 3.3): the link's angular velocity in the
ideal sensor frame, and the misalignment of the real sensor frame."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._kinematics import link_frames
from .._robot import Robot
from .._rotations import rot_x, rot_y, rot_z


def mount_angular_velocity(
    robot: Robot, q: Float[Array, " n"], qd: Float[Array, " n"], joint: Int[Array, ""] | int
) -> Float[Array, "3"]:
    """Angular velocity of the link after `joint` (0-based) in its ideal gyroscope frame: frame
    `joint - 1` (the base frame for joint 0) turned by `Rz(q_joint + offset_joint)`, whose z-axis is
    the joint axis. `omega = sum_{j <= joint} qd_j z_{j-1}` (world), rotated into that frame.
    Works with a traced `joint`."""
    frames = link_frames(robot, q)[:, :3, :3]
    prev = jnp.concatenate([robot.base[None, :3, :3], frames[:-1]], 0)
    omega_world = jnp.sum(jnp.where(jnp.arange(qd.shape[-1]) <= joint, qd, 0.0)[:, None] * prev[:, :, 2], 0)
    return (prev[joint] @ rot_z(q[joint] + robot.offset[joint])).T @ omega_world


def sensor_rotation(misalignment: Float[Array, "*b 2"]) -> Float[Array, "*b 3 3"]:
    """`Rx(alpha) Ry(beta)`: maps gyroscope-frame vectors into the ideal frame (eq. 3.3)."""
    return rot_x(misalignment[..., 0]) @ rot_y(misalignment[..., 1])
