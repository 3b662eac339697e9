"""The calibration's forward model with the per-pose constants of an LM solve hoisted (thesis 3.2.3).

`predict_pose` evaluates the gear inversion `phi = Xi^{-1}(theta)` (Newton on up to 12 ripple
harmonics per joint, eq. 2.13) and the direct kinematics (eq. 2.4) as batched 4x4 products.
In the LM only the free parameters change, so here
- `phi_j` is computed once (with the initial robot) for every joint whose `u0_j` is not free;
  a free `u0_j` of a ripple-free gear gives `phi_j = theta_j / u0_j` exactly; a free `u0_j` of
  a rippled gear keeps the full inversion (`jr.gear_output`);
- the kinematics run as elementwise 3x3 products of one pose (vmapped over poses), which XLA
  fuses into a few loops instead of many tiny batched matrix products.
`pose_model` agrees with `predict_pose` to rounding (tested).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

import jaxrobot as jr
from jaxrobot._kinematics import rot_x, rot_y

from ._parameters import ParameterMap, parse_name


def rippled_joints(robot: jr.Robot) -> tuple[int, ...]:
    """Joints (0-based) whose gear has ripple in either set, for any robot of a (fleet) pytree;
    all six when the robot is traced (then nothing can be skipped)."""
    orders = (robot.cw.orders, robot.ccw.orders)
    if any(isinstance(o, jax.core.Tracer) for o in orders):
        return tuple(range(6))
    used = np.concatenate([np.asarray(o).reshape(-1, 6, np.shape(o)[-1]) for o in orders], -1) > 0
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


def marker_pose_one(robot: jr.Robot, q: Float[Array, " 6"], marker: Float[Array, " 3"]
                    ) -> tuple[Float[Array, " 3"], Float[Array, "3 3"]]:
    """Marker position and rotation of one pose (eq. 2.2-2.4, `H = Rz(q + offset) Tx(a) Tz(d) Rx(alpha)
    Ry(beta)`), the same as `jaxrobot._bench_poses.marker_pose`."""
    rot, pos = _rows(robot.base[:3, :3]), [robot.base[i, 3] for i in range(3)]
    c, s = jnp.cos(q + robot.offset), jnp.sin(q + robot.offset)
    for i in range(6):
        xy = _rows(rot_x(robot.alpha[i]) @ rot_y(robot.beta[i]))  # per robot, not per pose
        rz_xy = [[c[i] * xy[0][k] - s[i] * xy[1][k] for k in range(3)],
                 [s[i] * xy[0][k] + c[i] * xy[1][k] for k in range(3)], xy[2]]
        pos = _add(pos, _mv(rot, [c[i] * robot.a[i], s[i] * robot.a[i], robot.d[i]]))
        rot = _mm(rot, rz_xy)
    pos = _add(pos, _mv(rot, [robot.tool[i, 3] for i in range(3)]))
    rot = _mm(rot, _rows(robot.tool[:3, :3]))
    pos = _add(pos, _mv(rot, [marker[i] for i in range(3)]))
    return jnp.stack(pos), jnp.stack([jnp.stack(r) for r in rot])


def joint_angle_model(
    robot0: jr.Robot,
    params: ParameterMap,
    theta: Float[Array, "K 6"],
    deflection: Float[Array, "K 6"],
    ccw: bool | Bool[Array, "K 6"] = False,
    rippled: tuple[int, ...] | None = None,
    q0: Float[Array, "K 6"] | None = None,
) -> tuple[Float[Array, "K 6"], Callable]:
    """Joint angles `q = Xi^{-1}(theta) + deflection` of robots that differ from `robot0` only in
    `params`: `q0` (K, 6) of `robot0` (the gear inversion of joints with fixed `u0` is done here,
    once, unless given) and `q_pose(robot, theta_k, q0_k, deflection_k, ccw_k)` for one pose."""
    rippled = rippled_joints(robot0) if rippled is None else rippled
    free_u0 = {j for j in range(6) if f"u0_{j + 1}" in params.names}
    q0 = jr.gear_output(robot0, theta, ccw) + deflection if q0 is None else q0
    full = bool(free_u0 & set(rippled))

    def q_pose(robot, th, q0k, dek, ccwk):
        if not free_u0:
            return q0k
        phi = jr.gear_output(robot, th, ccwk) if full else None
        cols = [q0k[j] if j not in free_u0 else (phi[j] if j in rippled else th[j] / robot.u0[j]) + dek[j]
                for j in range(6)]
        return jnp.stack(cols)

    return q0, q_pose


def _cross(u: list[Array], v: list[Array]) -> list[Array]:
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def analytic_names(names: tuple[str, ...]) -> bool:
    """Whether `position_jacobian_one` covers these parameters (joint fields a, d, alpha, beta,
    offset, u0; not the tool/base frames)."""
    return not any(n.startswith(("tool_", "base_")) for n in names)


def position_jacobian_one(
    robot: jr.Robot, params: ParameterMap, q: Float[Array, " 6"], theta: Float[Array, " 6"],
    ratio: Float[Array, " 6"], marker: Float[Array, " 3"],
) -> tuple[Float[Array, " 3"], Float[Array, "3 m"]]:
    """Marker position of one pose and its derivative by the free joint parameters, from the
    joint screws (thesis 3.2.2): with `z`, `x'` the z axis of frame i-1 and the x axis after
    `Rz(q_i + offset_i)`, `y''` the y axis after `Rx(alpha_i)`, `o_{i-1}`, `o_i` the frame origins,
    `dp/d offset_i = z x (p - o_{i-1})`, `dp/da_i = x'`, `dp/dd_i = z`, `dp/dalpha_i = x' x (p - o_i)`,
    `dp/dbeta_i = y'' x (p - o_i)` and `dp/du0_i = dp/d offset_i * dq_i/du0_i`, `dq_i/du0_i = -theta_i /
    (u0_i u_i(phi_i))` (`ratio` = `u_i(phi_i)`, implicit function of eq. 2.13)."""
    rot, pos = _rows(robot.base[:3, :3]), [robot.base[i, 3] for i in range(3)]
    c, s = jnp.cos(q + robot.offset), jnp.sin(q + robot.offset)
    screws = []
    for i in range(6):
        ca, sa = jnp.cos(robot.alpha[i]), jnp.sin(robot.alpha[i])
        xy = _rows(rot_x(robot.alpha[i]) @ rot_y(robot.beta[i]))
        z = [rot[k][2] for k in range(3)]
        x1 = [c[i] * rot[k][0] + s[i] * rot[k][1] for k in range(3)]
        y2 = _mv(rot, [-s[i] * ca, c[i] * ca, sa])
        o_prev = pos
        pos = [pos[k] + robot.a[i] * x1[k] + robot.d[i] * z[k] for k in range(3)]
        screws.append((z, x1, y2, o_prev, pos))
        rz_xy = [[c[i] * xy[0][k] - s[i] * xy[1][k] for k in range(3)],
                 [s[i] * xy[0][k] + c[i] * xy[1][k] for k in range(3)], xy[2]]
        rot = _mm(rot, rz_xy)
    pos = _add(pos, _mv(rot, [robot.tool[i, 3] for i in range(3)]))
    rot = _mm(rot, _rows(robot.tool[:3, :3]))
    p = _add(pos, _mv(rot, [marker[i] for i in range(3)]))
    cols = []
    for name in params.names:
        field, j = parse_name(name)
        z, x1, y2, o_prev, o = screws[j]
        rel_prev, rel = [p[k] - o_prev[k] for k in range(3)], [p[k] - o[k] for k in range(3)]
        if field == "a":
            col = x1
        elif field == "d":
            col = z
        elif field == "alpha":
            col = _cross(x1, rel)
        elif field == "beta":
            col = _cross(y2, rel)
        elif field == "offset":
            col = _cross(z, rel_prev)
        else:  # u0
            dq = -theta[j] / (robot.u0[j] * ratio[j])
            col = [dq * e for e in _cross(z, rel_prev)]
        cols.append(jnp.stack(col))
    return jnp.stack(p), jnp.stack(cols, -1)
