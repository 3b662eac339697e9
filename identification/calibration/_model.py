"""The calibration's forward model with the per-pose constants of an LM solve hoisted (thesis 3.2.3).

`predict_pose` evaluates the gear inversion `phi = Xi^{-1}(theta)` (Newton on up to 12 ripple
harmonics per joint, eq. 2.13) and the direct kinematics (eq. 2.4) as batched 4x4 products.
In the LM only the free parameters change, so here
- `phi_j` is computed once (with the initial robot) for every joint whose `u0_j` is not free;
  a free `u0_j` of a ripple-free gear gives `phi_j = theta_j / u0_j` exactly; a free `u0_j` of
  a rippled gear keeps the full inversion (`jr.gear_output`);
- the kinematics run as elementwise 3x3 products of one pose (vmapped over poses), which XLA
  fuses into a few loops instead of many tiny batched matrix products;
- the joint-screw Jacobian (`position_jacobian`) runs batch-last over any batch of robots and
  poses, its frame chain as a `lax.scan` over the joints (each frame computed once, not once per
  Jacobian column).
`pose_model` agrees with `predict_pose` to rounding (tested).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

import jaxrobot as jr

from ._parameters import ParameterMap, parse_name


def rippled_joints(robot: jr.Robot) -> tuple[int, ...]:
    """Joints (0-based) whose gear has ripple in either set, for any robot of a (fleet) pytree;
    all of them when the robot is traced (then nothing can be skipped)."""
    orders = (robot.cw.orders, robot.ccw.orders)
    n = robot.n_joints
    if any(isinstance(o, jax.core.Tracer) for o in orders):
        return tuple(range(n))
    used = np.concatenate([np.asarray(o).reshape(-1, n, np.shape(o)[-1]) for o in orders], -1) > 0
    return tuple(int(j) for j in np.nonzero(used.any((0, 2)))[0])


Mat = list[list[Array]]
"""A 3x3 matrix as nested lists of scalars: every product below is elementwise over the (vmapped)
poses, which XLA fuses into a few loops (tiny batched dots and reductions are slow on CPU)."""


def _mm(a: Mat, b: Mat) -> Mat:
    return [[a[i][0] * b[0][k] + a[i][1] * b[1][k] + a[i][2] * b[2][k] for k in range(3)] for i in range(3)]


def _mv(a: Mat, v: list[Array]) -> list[Array]:
    return [a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2] for i in range(3)]


def _add(u: list[Array], v: list[Array]) -> list[Array]:
    return [u[i] + v[i] for i in range(3)]


def _rows(m: Float[Array, "3 3"]) -> Mat:
    return [[m[i, k] for k in range(3)] for i in range(3)]


def _alpha_beta(robot: jr.Robot) -> Mat:
    """`Rx(alpha) Ry(beta)` of every joint (per robot, not per pose), entries (..., n)."""
    ca, sa, cb, sb = (f(x) for x in (robot.alpha, robot.beta) for f in (jnp.cos, jnp.sin))
    return [[cb, jnp.zeros_like(cb), sb], [sa * sb, ca, -sa * cb], [-ca * sb, sa, ca * cb]]


def _joint_step(rot: Mat, pos: list[Array], c, s, a, d, xy: Mat):
    """Frame i from frame i-1 (eq. 2.2-2.3, `H = Rz(q + offset) Tx(a) Tz(d) Rx(alpha) Ry(beta)`, `c`, `s` of
    `q + offset`): the new rotation and origin, and the z axis of frame i-1 and its x axis after `Rz`."""
    z = [rot[k][2] for k in range(3)]
    x1 = [c * rot[k][0] + s * rot[k][1] for k in range(3)]
    rz_xy = [[c * xy[0][k] - s * xy[1][k] for k in range(3)], [s * xy[0][k] + c * xy[1][k] for k in range(3)], xy[2]]
    return _mm(rot, rz_xy), [pos[k] + a * x1[k] + d * z[k] for k in range(3)], z, x1


def _tool_marker(robot: jr.Robot, rot: Mat, pos: list[Array], marker) -> tuple[list[Array], Mat]:
    """Marker position and rotation from the flange frame `rot`, `pos` (eq. 2.4 and the tool)."""
    pos = _add(pos, _mv(rot, [robot.tool[..., i, 3] for i in range(3)]))
    rot = _mm(rot, [[robot.tool[..., i, k] for k in range(3)] for i in range(3)])
    return _add(pos, _mv(rot, [marker[i] for i in range(3)])), rot


def marker_pose_one(robot: jr.Robot, q: Float[Array, " n"], marker: Float[Array, " 3"]
                    ) -> tuple[Float[Array, " 3"], Float[Array, "3 3"]]:
    """Marker position and rotation of one pose, the same as `jaxrobot.measurement.marker_pose`
    (unrolled over the joints: the whole chain fuses into a few loops over the poses)."""
    rot, pos = _rows(robot.base[:3, :3]), [robot.base[i, 3] for i in range(3)]
    c, s = jnp.cos(q + robot.offset), jnp.sin(q + robot.offset)
    xy = _alpha_beta(robot)
    for i in range(robot.n_joints):
        rot, pos, _, _ = _joint_step(rot, pos, c[i], s[i], robot.a[i], robot.d[i],
                                     [[e[i] for e in row] for row in xy])
    pos, rot = _tool_marker(robot, rot, pos, marker)
    return jnp.stack(pos), jnp.stack([jnp.stack(r) for r in rot])


def joint_angle_model(
    robot0: jr.Robot,
    params: ParameterMap,
    theta: Float[Array, "K n"],
    deflection: Float[Array, "K n"],
    ccw: bool | Bool[Array, "K n"] = False,
    rippled: tuple[int, ...] | None = None,
    q0: Float[Array, "K n"] | None = None,
) -> tuple[Float[Array, "K n"], Callable]:
    """Joint angles `q = Xi^{-1}(theta) + deflection` of robots that differ from `robot0` only in
    `params`: `q0` (K, n) of `robot0` (the gear inversion of joints with fixed `u0` is done here,
    once, unless given) and `q_pose(robot, theta_k, q0_k, deflection_k, ccw_k)` for one pose."""
    rippled = rippled_joints(robot0) if rippled is None else rippled
    joints = range(robot0.n_joints)
    free_u0 = {j for j in joints if f"u0_{j + 1}" in params.names}
    q0 = jr.gear_output(robot0, theta, ccw) + deflection if q0 is None else q0
    full = bool(free_u0 & set(rippled))

    def q_pose(robot, th, q0k, dek, ccwk):
        if not free_u0:
            return q0k
        phi = jr.gear_output(robot, th, ccwk) if full else None
        cols = [q0k[j] if j not in free_u0 else (phi[j] if j in rippled else th[j] / robot.u0[j]) + dek[j]
                for j in joints]
        return jnp.stack(cols)

    return q0, q_pose


def _cross(u: list[Array], v: list[Array]) -> list[Array]:
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def analytic_names(names: tuple[str, ...]) -> bool:
    """Whether `position_jacobian_one` covers these parameters (joint fields a, d, alpha, beta,
    offset, u0; not the tool/base frames)."""
    return not any(n.startswith(("tool_", "base_")) for n in names)


def position_jacobian_one(
    robot: jr.Robot, params: ParameterMap, q: Float[Array, " n"], theta: Float[Array, " n"],
    ratio: Float[Array, " n"], marker: Float[Array, " 3"],
) -> tuple[Float[Array, " 3"], Float[Array, "3 m"]]:
    """`position_jacobian` of one pose: marker position (3,) and its Jacobian (3, m)."""
    p, jac = position_jacobian(robot, params, q, theta, ratio, marker)
    return p, jac.T


def position_jacobian(
    robot: jr.Robot, params: ParameterMap, q: Float[Array, "*b n"], theta: Float[Array, "*b n"],
    ratio: Float[Array, "*b n"], marker: Float[Array, " 3"],
) -> tuple[Float[Array, "3 ..."], Float[Array, "m 3 ..."]]:
    """Marker position and its derivative by the free joint parameters, from the joint screws
    (thesis 3.2.2), batch-last: the robot's fields broadcast against the batch `*b` of `q` (a fleet
    as fields (R, 1, ...) against poses (R, K, n)); results have the batch on the trailing axes.

    With `z`, `x'` the z axis of frame i-1 and the x axis after `Rz(q_i + offset_i)`, `y''` the y
    axis after `Rx(alpha_i)`, `o_{i-1}`, `o_i` the frame origins (eq. 2.2-2.4):
    `dp/d offset_i = z x (p - o_{i-1})`, `dp/da_i = x'`, `dp/dd_i = z`, `dp/dalpha_i = x' x (p - o_i)`,
    `dp/dbeta_i = y'' x (p - o_i)` and `dp/du0_i = dp/d offset_i * dq_i/du0_i`, `dq_i/du0_i = -theta_i /
    (u0_i u_i(phi_i))` (`ratio` = `u_i(phi_i)`, implicit function of eq. 2.13).
    The chain runs as a `lax.scan` over the joints on elementwise (batch-shaped) arrays: unrolled,
    XLA CPU fuses the whole chain into every Jacobian column and evaluates it m times.
    """
    batch = jnp.broadcast_shapes(q.shape[:-1], robot.a.shape[:-1])
    joint_first = lambda f: jnp.moveaxis(f, -1, 0)  # noqa: E731  (*b, n) -> (n, *b)
    ang = joint_first(q + robot.offset)
    xy = [[joint_first(e) for e in row] for row in _alpha_beta(robot)]
    xs = (jnp.cos(ang), jnp.sin(ang), joint_first(robot.a), joint_first(robot.d), xy)

    def step(frame, x):
        rot, pos = frame
        c, s, a, d, xy = x
        y2 = _mv(rot, [-s * xy[1][1], c * xy[1][1], xy[2][1]])  # Rz (0, cos alpha, sin alpha)
        rot_new, pos_new, z, x1 = _joint_step(rot, pos, c, s, a, d, xy)
        return (rot_new, pos_new), (z, x1, y2, pos, pos_new)

    full = lambda x: jnp.broadcast_to(x, batch)  # noqa: E731
    frame0 = ([[full(robot.base[..., i, k]) for k in range(3)] for i in range(3)],
              [full(robot.base[..., i, 3]) for i in range(3)])
    (rot, pos), (z, x1, y2, o_prev, o) = jax.lax.scan(step, frame0, xs)
    p, _ = _tool_marker(robot, rot, pos, marker)
    cols = []
    for name in params.names:
        field, j = parse_name(name)
        at = lambda v: [e[j] for e in v]  # noqa: E731
        rel_prev, rel = [p[k] - o_prev[k][j] for k in range(3)], [p[k] - o[k][j] for k in range(3)]
        if field == "a":
            col = at(x1)
        elif field == "d":
            col = at(z)
        elif field == "alpha":
            col = _cross(at(x1), rel)
        elif field == "beta":
            col = _cross(at(y2), rel)
        elif field == "offset":
            col = _cross(at(z), rel_prev)
        else:  # u0
            dq = -theta[..., j] / (robot.u0[..., j] * ratio[..., j])
            col = [dq * e for e in _cross(at(z), rel_prev)]
        cols.append(jnp.stack([full(e) for e in col]))
    return jnp.stack(p), jnp.stack(cols)
