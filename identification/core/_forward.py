"""The calibration's forward model with the per-pose constants of an LM solve hoisted (thesis 3.2.3).

`predict_pose` evaluates the gear inversion `phi = Xi^{-1}(theta)` (Newton on up to 12 ripple
harmonics per joint, eq. 2.13) and the direct kinematics (eq. 2.4, `jaxrobot.measurement.marker_pose`).
In the LM only the free parameters change, so here
- `phi_j` is computed once (with the initial robot) for every joint whose `u0_j` is not free;
  a free `u0_j` of a ripple-free gear gives `phi_j = theta_j / u0_j` exactly; a free `u0_j` of
  a rippled gear keeps the full inversion (`jr.gear_output`);
- the joint-screw Jacobian (`position_jacobian`) takes the columns of the free parameters from
  `jaxrobot.identification_jacobian`.
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


def analytic_names(names: tuple[str, ...]) -> bool:
    """Whether `position_jacobian` covers these parameters (joint fields a, d, alpha, beta,
    offset, u0; not the tool/base frames)."""
    return not any(n.startswith(("tool_", "base_")) for n in names)


_COLUMN = {"alpha": 0, "beta": 1, "a": 2, "d": 3, "offset": 4}
"""Fields of `jaxrobot.identification_jacobian`, in its order."""


def position_jacobian(
    robot: jr.Robot, params: ParameterMap, q: Float[Array, "*b n"], theta: Float[Array, "*b n"],
    ratio: Float[Array, "*b n"], marker: Float[Array, " 3"],
) -> tuple[Float[Array, "*b 3"], Float[Array, "*b 3 m"]]:
    """Marker position and its derivative by the free joint parameters (`analytic_names`), from the
    joint screws (`jaxrobot.identification_jacobian`, thesis 3.2.2); the robot's fields broadcast
    against the batch `*b` of `q` (a fleet as fields (R, 1, ...) against poses (R, K, n)).

    `dp/du0_i = dp/d offset_i * dq_i/du0_i`, `dq_i/du0_i = -theta_i / (u0_i u_i(phi_i))` (`ratio` =
    `u_i(phi_i)`, implicit function of eq. 2.13).
    """
    p, jac = jr.identification_jacobian(robot, q, marker)
    cols = []
    for name in params.names:
        field, j = parse_name(name)
        if field == "u0":
            dq = -theta[..., j] / (robot.u0[..., j] * ratio[..., j])
            cols.append(jac[..., _COLUMN["offset"], j] * dq[..., None])
        else:
            cols.append(jac[..., _COLUMN[field], j])
    return p, jnp.stack(cols, -1)
