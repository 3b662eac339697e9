"""Rotations and homogeneous transforms: elementary rotations, roll-pitch-yaw, quaternions and
rotation vectors (eq. 2.1). All functions broadcast over leading batch axes."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def rot_x(t: Float[Array, "*b"]) -> Float[Array, "*b 3 3"]:
    """Rotation by `t` [rad] about the x axis."""
    c, s, o, z = jnp.cos(t), jnp.sin(t), jnp.ones_like(t), jnp.zeros_like(t)
    return jnp.stack([jnp.stack([o, z, z], -1), jnp.stack([z, c, -s], -1), jnp.stack([z, s, c], -1)], -2)


def rot_y(t: Float[Array, "*b"]) -> Float[Array, "*b 3 3"]:
    """Rotation by `t` [rad] about the y axis."""
    c, s, o, z = jnp.cos(t), jnp.sin(t), jnp.ones_like(t), jnp.zeros_like(t)
    return jnp.stack([jnp.stack([c, z, s], -1), jnp.stack([z, o, z], -1), jnp.stack([-s, z, c], -1)], -2)


def rot_z(t: Float[Array, "*b"]) -> Float[Array, "*b 3 3"]:
    """Rotation by `t` [rad] about the z axis."""
    c, s, o, z = jnp.cos(t), jnp.sin(t), jnp.ones_like(t), jnp.zeros_like(t)
    return jnp.stack([jnp.stack([c, -s, z], -1), jnp.stack([s, c, z], -1), jnp.stack([z, z, o], -1)], -2)


def homogeneous(r: Float[Array, "*b 3 3"], p: Float[Array, "*b 3"]) -> Float[Array, "*b 4 4"]:
    """`[[R, p], [0, 1]]` (eq. 2.1)."""
    r, p = jnp.broadcast_arrays(r, p[..., None])
    top = jnp.concatenate([r, p[..., :1]], -1)
    bottom = jnp.broadcast_to(jnp.array([0.0, 0.0, 0.0, 1.0]), top.shape[:-2] + (1, 4))
    return jnp.concatenate([top, bottom], -2)


def rpy(r: Float[Array, "*b 3 3"]) -> Float[Array, "*b 3"]:
    """Roll-pitch-yaw angles (`R = Rz(yaw) Ry(pitch) Rx(roll)`) of a rotation matrix."""
    roll = jnp.arctan2(r[..., 2, 1], r[..., 2, 2])
    pitch = jnp.arctan2(-r[..., 2, 0], jnp.hypot(r[..., 2, 1], r[..., 2, 2]))
    yaw = jnp.arctan2(r[..., 1, 0], r[..., 0, 0])
    return jnp.stack([roll, pitch, yaw], -1)


def vee(w: Float[Array, "*b 3 3"]) -> Float[Array, "*b 3"]:
    """Axial vector of the antisymmetric part of `w`: `(w32 - w23, w13 - w31, w21 - w12) / 2`."""
    return 0.5 * jnp.stack([w[..., 2, 1] - w[..., 1, 2], w[..., 0, 2] - w[..., 2, 0],
                            w[..., 1, 0] - w[..., 0, 1]], -1)


def rotation_error(r_meas: Float[Array, "*b 3 3"], r_model: Float[Array, "*b 3 3"]) -> Float[Array, "*b 3"]:
    """Small-angle rotation vector of `r_meas^T r_model` (rad; exact to second order)."""
    return vee(jnp.einsum("...ji,...jk->...ik", r_meas, r_model))


def pose_vector(t: Float[Array, "*b 4 4"]) -> Float[Array, "*b 6"]:
    """Translation [m] and roll-pitch-yaw [rad] `(x, y, z, rx, ry, rz)` of a homogeneous transform."""
    return jnp.concatenate([t[..., :3, 3], rpy(t[..., :3, :3])], -1)


def pose_matrix(v: Float[Array, "*b 6"]) -> Float[Array, "*b 4 4"]:
    """Homogeneous transform of `(x, y, z, rx, ry, rz)`: `R = Rz(rz) Ry(ry) Rx(rx)` (inverse of `pose_vector`)."""
    return homogeneous(rot_z(v[..., 5]) @ rot_y(v[..., 4]) @ rot_x(v[..., 3]), v[..., :3])


def rotation_to_quaternion(r: Float[Array, "*b 3 3"]) -> Float[Array, "*b 4"]:
    """Unit quaternion (qx, qy, qz, qw), qw >= 0, of a rotation matrix (branch-free Shepperd)."""
    tr = r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]
    cands = jnp.stack([
        jnp.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1],
                   1.0 + tr], -1),
        jnp.stack([1.0 + 2 * r[..., 0, 0] - tr, r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0],
                   r[..., 2, 1] - r[..., 1, 2]], -1),
        jnp.stack([r[..., 0, 1] + r[..., 1, 0], 1.0 + 2 * r[..., 1, 1] - tr, r[..., 1, 2] + r[..., 2, 1],
                   r[..., 0, 2] - r[..., 2, 0]], -1),
        jnp.stack([r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1], 1.0 + 2 * r[..., 2, 2] - tr,
                   r[..., 1, 0] - r[..., 0, 1]], -1),
    ], -2)  # each row is 4 * q_k * q, largest for the largest |q_k|
    diag = jnp.stack([1.0 + tr, 1.0 + 2 * r[..., 0, 0] - tr, 1.0 + 2 * r[..., 1, 1] - tr,
                      1.0 + 2 * r[..., 2, 2] - tr], -1)
    best = jnp.argmax(diag, -1)
    q = jnp.take_along_axis(cands, best[..., None, None], -2)[..., 0, :]
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    return q * jnp.where(q[..., 3:] < 0, -1.0, 1.0)


def quaternion_to_rotation(quat: Float[Array, "*b 4"]) -> Float[Array, "*b 3 3"]:
    """Rotation matrix of a quaternion (qx, qy, qz, qw); the quaternion is normalised first."""
    quat = quat / jnp.linalg.norm(quat, axis=-1, keepdims=True)
    x, y, z, w = (quat[..., i] for i in range(4))
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        jnp.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        jnp.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rotvec_to_rotation(w: Float[Array, "*b 3"]) -> Float[Array, "*b 3 3"]:
    """Rotation matrix of a rotation vector (axis times angle [rad])."""
    angle = jnp.linalg.norm(w, axis=-1)
    half = 0.5 * angle
    scale = jnp.where(angle > 0, jnp.sin(half) / jnp.where(angle > 0, angle, 1.0), 0.5)
    return quaternion_to_rotation(jnp.concatenate([w * scale[..., None], jnp.cos(half)[..., None]], -1))
