"""Forward kinematics in standard DH parameters plus the Hayati angle, eq. 2.2-2.4, and Jacobians.

All public functions broadcast over leading batch axes of `robot` and `q`. The one chain,
`frame_chain`, and everything built on it (the calibration's model and Jacobian, the mass matrix
and gravity torques) run on a small elementwise 3x3 algebra: a `Vec` is a list of 3 arrays, a `Mat`
a list of 3 rows of 3, all of one broadcastable shape in any layout (batch-last in the dynamics,
scalars under `vmap` in the calibration). XLA fuses these sums of products into a few loops over
the batch, where tiny batched matrix products and size-3 reductions each become a separate, slow
kernel on the CPU.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._batch import link_unroll, unbatched
from ._robot import Robot
from ._rotations import rpy

Vec = list[Array]
"""A 3-vector as a list of its components, arrays of one broadcastable shape."""
Mat = list[list[Array]]
"""A 3x3 matrix as a list of rows of entries, arrays of one broadcastable shape."""


def mm(a: Mat, b: Mat) -> Mat:
    return [[a[i][0] * b[0][k] + a[i][1] * b[1][k] + a[i][2] * b[2][k] for k in range(3)] for i in range(3)]


def mv(a: Mat, v: Vec) -> Vec:
    return [a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2] for i in range(3)]


def transpose(a: Mat) -> Mat:
    return [[a[k][i] for k in range(3)] for i in range(3)]


def add(u: Vec, v: Vec) -> Vec:
    return [u[i] + v[i] for i in range(3)]


def sub(u: Vec, v: Vec) -> Vec:
    return [u[i] - v[i] for i in range(3)]


def scale(s, v: Vec) -> Vec:
    return [s * e for e in v]


def cross(u: Vec, v: Vec) -> Vec:
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def dot(u: Vec, v: Vec):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def column(a: Mat, k: int) -> Vec:
    return [a[i][k] for i in range(3)]


def _at(x: Array, i: int, axis: int) -> Array:
    """`x` at index `i` of `axis` (a slice: no transpose)."""
    return x[(slice(None),) * axis + (i,)] if axis >= 0 else x[(..., i) + (slice(None),) * (-axis - 1)]


def vec(x: Array, axis: int = -1) -> Vec:
    """The components of the 3-vectors of `x` along `axis`."""
    return [_at(x, i, axis) for i in range(3)]


def mat(x: Array, axis: int = -2) -> Mat:
    """The entries of the 3x3 matrices of `x` with rows along `axis` and columns along the next axis."""
    return [vec(_at(x, i, axis), axis if axis >= 0 else axis + 1) for i in range(3)]


def stack_vec(v: Vec, axis: int = -1) -> Array:
    """`v` as an array with the components along `axis` (inverse of `vec`)."""
    return jnp.stack(jnp.broadcast_arrays(*v), axis)


def stack_mat(a: Mat, axis: int = -2) -> Array:
    """`a` as an array with rows along `axis` and columns along the next axis (inverse of `mat`)."""
    entries = jnp.broadcast_arrays(*(e for row in a for e in row))
    rows = [jnp.stack(entries[3 * i:3 * i + 3], axis + 1 if axis < 0 else axis) for i in range(len(a))]
    return jnp.stack(rows, axis)


def _homogeneous(r: Mat, p: Vec) -> Array:
    """`[[R, p], [0, 1]]` (eq. 2.1) as an array (..., 4, 4)."""
    top = jnp.broadcast_arrays(*(e for i in range(3) for e in r[i] + [p[i]]))
    zero, one = jnp.zeros_like(top[0]), jnp.ones_like(top[0])
    return jnp.stack([*top, zero, zero, zero, one], -1).reshape(top[0].shape + (4, 4))


def alpha_beta(alpha, beta) -> Mat:
    """`Rx(alpha) Ry(beta)`."""
    ca, sa, cb, sb = jnp.cos(alpha), jnp.sin(alpha), jnp.cos(beta), jnp.sin(beta)
    return [[cb, jnp.zeros_like(cb), sb], [sa * sb, ca, -sa * cb], [-ca * sb, sa, ca * cb]]


def joint_step(c, s, a, d, xy: Mat) -> tuple[Mat, Vec]:
    """Rotation and origin of frame i in frame i-1 (eq. 2.2-2.3),
    `H_{i-1}^i = Rz(q_i + offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`, from `c`, `s` =
    cos, sin of `q_i + offset_i` and `xy = Rx(alpha_i) Ry(beta_i)`."""
    rz_xy = [[c * xy[0][k] - s * xy[1][k] for k in range(3)], [s * xy[0][k] + c * xy[1][k] for k in range(3)], xy[2]]
    return rz_xy, [c * a, s * a, d]


def dh_transform(theta, a, d, alpha, beta) -> Float[Array, "*b 4 4"]:
    """`Rz(theta) Tx(a) Tz(d) Rx(alpha) Ry(beta)` (eq. 2.2-2.3) as a 4x4 matrix (broadcasts)."""
    return _homogeneous(*joint_step(jnp.cos(theta), jnp.sin(theta), a, d, alpha_beta(alpha, beta)))


class Chain(eqx.Module):
    """Frames 1..n of a chain (eq. 2.4) and the axes of joint i, per joint on a leading axis."""

    rotation: Mat
    """`R_0^i`, the world rotation of frame i."""
    origin: Vec
    """`o_i`, the world origin of frame i."""
    pivot: Vec
    """`o_{i-1}`, the origin of frame i-1, on the axis of joint i."""
    z: Vec
    """`z_{i-1}`, the z axis of frame i-1: the axis of joint i (and of `d_i`)."""
    x: Vec
    """The x axis after `Rz(q_i + offset_i)`: the direction of `a_i`, the axis of `alpha_i`."""
    y: Vec
    """The y axis after `Rx(alpha_i)`: the axis of `beta_i` (the y axis of frame i)."""


def _frame_step(rot: Mat, pos: Vec, c, s, a, d, xy: Mat) -> tuple[Mat, Vec, Vec]:
    """Frame i from frame i-1 (`joint_step`): its rotation and origin, and the x axis after `Rz`."""
    r_loc, p_loc = joint_step(c, s, a, d, xy)
    x1 = add(scale(c, column(rot, 0)), scale(s, column(rot, 1)))
    return mm(rot, r_loc), add(pos, mv(rot, p_loc)), x1


def frame_chain(base_r: Mat, base_p: Vec, theta, a, d, alpha, beta, stacked: bool = False
                ) -> tuple[tuple[Mat, Vec], Chain]:
    """World frames of the joints by `H_0^i = H_0^{i-1} H_{i-1}^i` (eq. 2.2-2.4) from the base
    frame `base_r`, `base_p`, as a `lax.scan` over the joints (one loop body to compile, where an unrolled chain
    repeats its reverse mode per joint). `stacked`: the scan carries one array per frame part instead of one per
    entry (fewer kernels per step, for small batches such as the dynamics' chunks; separate entries
    suit large batches).

    `theta = q + offset`, `a`, `d`, `alpha`, `beta`: joint first, (n, *b) broadcastable with the
    base's entries (*b), in any layout. Returns the last frame (`R_0^n`, `o_n`) and the `Chain` of
    all joints (entries (n, *b)); under `jit` the parts not used are not computed.
    """
    xy = alpha_beta(alpha, beta)
    batch = jnp.broadcast_shapes(*(jnp.shape(e)[1:] for e in (theta, a, d, *xy[0], *xy[1], *xy[2])),
                                 *(jnp.shape(e) for e in (*base_r[0], *base_r[1], *base_r[2], *base_p)))
    frame0 = jax.tree.map(lambda e: jnp.broadcast_to(e, batch), (base_r, base_p))
    c, s = jnp.cos(theta), jnp.sin(theta)
    sm, sv = (lambda m: stack_mat(m, 0), lambda v: stack_vec(v, 0)) if stacked else (lambda m: m, lambda v: v)
    um, uv = (lambda m: mat(m, 0), lambda v: vec(v, 0)) if stacked else (lambda m: m, lambda v: v)

    def step(frame, x):
        rot, pos, x1 = _frame_step(um(frame[0]), uv(frame[1]), *x[:4], mat(x[4], 0))
        new = (sm(rot), sv(pos))
        return new, (*new, sv(x1))

    end, (rots, origins, x1) = jax.lax.scan(step, (sm(frame0[0]), sv(frame0[1])), (c, s, a, d, stack_mat(xy, 1)),
                                            unroll=link_unroll())
    end = (um(end[0]), uv(end[1]))
    if stacked:
        rots, origins, x1 = mat(rots, 1), vec(origins, 1), vec(x1, 1)
    shift = lambda first, v: jax.tree.map(lambda f, e: jnp.concatenate([f[None], e[:-1]]), first, v)  # noqa: E731
    return end, Chain(rots, origins, shift(frame0[1], origins), shift(column(frame0[0], 2), column(rots, 2)), x1,
                      column(rots, 1))


def _joint_first(robot: Robot, q: Array) -> tuple[Array, ...]:
    """`theta = q + offset`, `a`, `d`, `alpha`, `beta` of batch-first `robot` (*rb, n) and `q`
    (*b, n), joint first (n, *batch)."""
    rank = max(q.ndim, robot.a.ndim)
    first = lambda x: jnp.moveaxis(x.reshape((1,) * (rank - x.ndim) + x.shape), -1, 0)  # noqa: E731
    return tuple(first(x) for x in (q + robot.offset, robot.a, robot.d, robot.alpha, robot.beta))


def _chain(robot: Robot, q: Array) -> tuple[tuple[Mat, Vec], Chain]:
    """`frame_chain` of batch-first `robot` and `q` from `robot.base`."""
    return frame_chain(mat(robot.base[..., :3, :3]), vec(robot.base[..., :3, 3]), *_joint_first(robot, q))


def _tool_frame(robot: Robot, rot: Mat, pos: Vec) -> tuple[Mat, Vec]:
    """World rotation and origin of the tool frame from the flange frame `rot`, `pos`."""
    return mm(rot, mat(robot.tool[..., :3, :3])), add(pos, mv(rot, vec(robot.tool[..., :3, 3])))


def link_frames(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b n 4 4"]:
    """World poses of the DH frames 1..n (eq. 2.4); the flange is frame n."""
    _, chain = _chain(robot, q)
    return jnp.moveaxis(_homogeneous(chain.rotation, chain.origin), 0, -3)


def forward_kinematics(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 4 4"]:
    """Flange pose `T_0^n = [[R_e, p_e], [0, 1]]` (eq. 2.4) in the world frame."""
    (rot, pos), _ = _chain(robot, q)
    return _homogeneous(rot, pos)


def tool_pose(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 4 4"]:
    """Pose of the tool frame: flange pose times `robot.tool`."""
    (rot, pos), _ = _chain(robot, q)
    return _homogeneous(*_tool_frame(robot, rot, pos))


def point_position(
    robot: Robot, q: Float[Array, "*b n"], point: Float[Array, "*b 3"]
) -> Float[Array, "*b 3"]:
    """World position of a point fixed in the flange frame (e.g. a tracker marker)."""
    (rot, pos), _ = _chain(robot, q)
    return stack_vec(add(pos, mv(rot, vec(point))))


def marker_pose(
    robot: Robot, q: Float[Array, "*b n"], marker: Float[Array, "*b 3"]
) -> tuple[Float[Array, "*b 3"], Float[Array, "*b 3 3"]]:
    """World position and rotation of a marker body at `marker` in the tool frame (eq. 2.4).

    With the identity tool this is `jr.point_position(robot, q, marker)` and the flange rotation.
    """
    (rot, pos), _ = _chain(robot, q)
    rot, pos = _tool_frame(robot, rot, pos)
    return stack_vec(add(pos, mv(rot, vec(marker)))), stack_mat(rot)


def identification_jacobian(
    robot: Robot, q: Float[Array, "*b n"], point: Float[Array, "*b 3"]
) -> tuple[Float[Array, "*b 3"], Float[Array, "*b 3 5 n"]]:
    """World position `p` of a point fixed in the tool frame (e.g. a tracker marker) and the
    identification Jacobian (thesis 3.2.2): the derivatives of `p` by `alpha_i`, `beta_i`, `a_i`,
    `d_i` and `offset_i` (the same as by `q_i`) of every joint, in this order, from the joint screws.

    With `z`, `x'`, `y''` the axes of joint i (`Chain`) and `o_{i-1}`, `o_i` the frame origins:
    `dp/dalpha_i = x' x (p - o_i)`, `dp/dbeta_i = y'' x (p - o_i)`, `dp/da_i = x'`, `dp/dd_i = z`,
    `dp/doffset_i = z x (p - o_{i-1})`.
    """
    (rot, pos), chain = _chain(robot, q)
    rot, pos = _tool_frame(robot, rot, pos)
    p = add(pos, mv(rot, vec(point)))
    rel, rel_prev = sub([e[None] for e in p], chain.origin), sub([e[None] for e in p], chain.pivot)
    columns = (cross(chain.x, rel), cross(chain.y, rel), chain.x, chain.z, cross(chain.z, rel_prev))
    jac = jnp.stack([jnp.stack(jnp.broadcast_arrays(*c)) for c in columns])  # (5, 3, n, *b)
    return stack_vec(p), jnp.moveaxis(jac, (0, 1, 2), (-2, -3, -1))


def geometric_jacobian(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 6 n"]:
    """Geometric Jacobian `[v; omega] = J qd` of the tool frame, world axes: column i is
    `[z_{i-1} x (p - o_{i-1}); z_{i-1}]` (`Chain`, `p` the tool origin)."""
    (rot, pos), chain = _chain(robot, q)
    _, p = _tool_frame(robot, rot, pos)
    jv = cross(chain.z, sub([e[None] for e in p], chain.pivot))
    rows = jnp.stack(jnp.broadcast_arrays(*jv, *chain.z))  # (6, n, *b)
    return jnp.moveaxis(rows, (0, 1), (-2, -1))


def analytic_jacobian(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 6 n"]:
    """Analytic Jacobian `d[p; rpy]/dq` of the tool frame (roll-pitch-yaw; autodiff)."""

    def fn(robot, q):
        def pose(q):
            t = tool_pose(robot, q)
            return jnp.concatenate([t[:3, 3], rpy(t[:3, :3])])

        return jax.jacfwd(pose)(q)

    return unbatched(robot, q, fn)
