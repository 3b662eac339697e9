"""Forward kinematics in standard DH parameters plus the Hayati angle, eq. 2.2-2.4, and Jacobians.

All functions broadcast over leading batch axes of `robot` and `q`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._batch import unbatched
from ._robot import Robot
from ._rotations import homogeneous, rot_x, rot_y, rot_z, rpy, vee


def joint_rotation_translation(
    robot: Robot, q: Float[Array, "*b n"]
) -> tuple[Float[Array, "*b n 3 3"], Float[Array, "*b n 3"]]:
    """Rotation `R_i` and origin `p_i` of frame i in frame i-1 for all joints (eq. 2.2-2.3).

    `H_{i-1}^i = Rz(q_i + offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`.
    """
    rz = rot_z(q + robot.offset)
    r = rz @ rot_x(robot.alpha) @ rot_y(robot.beta)
    local = jnp.stack(jnp.broadcast_arrays(robot.a, jnp.zeros_like(robot.a), robot.d), -1)
    p = jnp.einsum("...ij,...j->...i", rz, local)
    return r, p


def joint_transforms(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b n 4 4"]:
    """Homogeneous transforms `T_{i-1}^i` of the n joints (eq. 2.2-2.3)."""
    return homogeneous(*joint_rotation_translation(robot, q))


def link_frames(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b n 4 4"]:
    """World poses of the DH frames 1..n (eq. 2.4); the flange is frame n."""
    t = joint_transforms(robot, q)
    base = jnp.broadcast_to(robot.base, t.shape[:-3] + (4, 4))

    def step(carry, t_i):
        pose = carry @ t_i
        return pose, pose

    _, frames = jax.lax.scan(step, base, jnp.moveaxis(t, -3, 0))
    return jnp.moveaxis(frames, 0, -3)


def forward_kinematics(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 4 4"]:
    """Flange pose `T_0^n = [[R_e, p_e], [0, 1]]` (eq. 2.4) in the world frame."""
    return link_frames(robot, q)[..., -1, :, :]


def tool_pose(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 4 4"]:
    """Pose of the tool frame: flange pose times `robot.tool`."""
    return forward_kinematics(robot, q) @ robot.tool


def point_position(
    robot: Robot, q: Float[Array, "*b n"], point: Float[Array, "*b 3"]
) -> Float[Array, "*b 3"]:
    """World position of a point fixed in the flange frame (e.g. a tracker marker)."""
    t = forward_kinematics(robot, q)
    return t[..., :3, 3] + jnp.einsum("...ij,...j->...i", t[..., :3, :3], point)


def geometric_jacobian(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 6 n"]:
    """Geometric Jacobian `[v; omega] = J qd` of the tool frame, world axes (autodiff)."""
    return unbatched(robot, q, _geometric_jacobian)


def _geometric_jacobian(robot: Robot, q: Float[Array, " n"]) -> Float[Array, "6 n"]:
    pose = lambda q: tool_pose(robot, q)  # noqa: E731
    t, dt = pose(q), jax.jacfwd(pose)(q)  # dt: (4, 4, n)
    jv = dt[:3, 3, :]
    jw = vee(jnp.einsum("ijk,lj->kil", dt[:3, :3, :], t[:3, :3]))  # (n, 3)
    return jnp.concatenate([jv, jw.T], 0)


def analytic_jacobian(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 6 n"]:
    """Analytic Jacobian `d[p; rpy]/dq` of the tool frame (roll-pitch-yaw; autodiff)."""

    def fn(robot, q):
        def pose(q):
            t = tool_pose(robot, q)
            return jnp.concatenate([t[:3, 3], rpy(t[:3, :3])])

        return jax.jacfwd(pose)(q)

    return unbatched(robot, q, fn)
