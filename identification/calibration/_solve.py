"""The Levenberg-Marquardt solve of one robot's kinematic calibration (thesis 3.2.3, eq. 3.12).

`min_v sum_i ||p_e(v, theta_i) - p_{e,m,i}||^2` over the free parameters `v`, with the forward
model of `predict_pose` (motor angles -> `Xi^{-1}` -> plus gravity deflection -> marker), solved
with `optx.least_squares` + `optx.LevenbergMarquardt` in scaled variables (1 mm, 1 mrad, 1e-3
of a gear ratio), optionally with pose weights (the robust losses' reweighting), whitened position rows (a
laser tracker's noise model) and Gaussian priors (MAP). The parameter covariance is
`s^2 (J^T W J)^{-1}` (`W` the pose weights) with the noise estimate `s^2 = ||r||^2 / (n - m)` over the `n`
residuals, `m` parameters.

The model is `predict_pose` with the per-pose constants of the solve hoisted (the fleets' batched LM,
`_fleet`, runs the same model): only the free parameters change, so
- `phi_j = Xi^{-1}(theta_j)` (Newton on up to 12 ripple harmonics per joint, eq. 2.13) is computed once, with
  the initial robot, for every joint whose `u0_j` is not free; a free `u0_j` of a ripple-free gear gives
  `phi_j = theta_j / u0_j` exactly; a free `u0_j` of a rippled gear keeps the full inversion (`jr.gear_output`)
  (`joint_angle_model`);
- the Jacobian of the marker position by the joint parameters comes from the joint screws
  (`position_jacobian`: the columns of the free parameters of `jaxrobot.identification_jacobian`, thesis 3.2.2).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

import jaxrobot as jr
from jaxrobot import RESULTS
from jaxrobot.internal import cached_program, check
from jaxrobot.measurement import marker_pose, rest_link_angles

from ..core._parameters import ParameterMap, parse_name, predict_pose

RESIDUAL_UNIT = 1e-3
"""Residuals are solved in mm (and orientation in units of the position/orientation noise ratio)."""


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


def position_errors(
    robot: jr.Robot, motor_angles, positions, deflection, marker, ccw=False
) -> np.ndarray:
    """Euclidean distance [m] between model and measured marker positions, per pose."""
    p, _ = _predict(robot, jnp.asarray(motor_angles), jnp.asarray(deflection), jnp.asarray(marker), ccw)
    return np.linalg.norm(np.asarray(p) - np.asarray(positions), axis=-1)


@eqx.filter_jit
def _predict(robot, theta, deflection, marker, ccw):
    return predict_pose(robot, theta, deflection, marker, ccw)


@eqx.filter_jit
def rest_pose(
    robot: jr.Robot, theta: Float[Array, "K n"], ccw: bool | Bool[Array, "K n"] = False
) -> tuple[Float[Array, "K n"], Float[Array, "K n"]]:
    """The per-pose constants of a calibration at motor angles `theta` in the start `robot` (thesis 3.2.3): the link
    angles at rest `q = Xi^{-1}(theta) + deflection` (`joint_angle_model`'s `q0`) and the gravity deflection
    `Delta phi_g`, the rest angles of `jaxrobot.measurement.rest_link_angles` (NaN where their fixed point did not
    converge) less `Xi^{-1}(theta)`.

    The calibration keeps the deflection of the start robot fixed: it depends on the kinematic deviations only
    through `g(q)`, a relative effect of ~1e-4 on a deflection of ~1e-4 rad (~1e-8 rad, far below the tracker
    noise).
    """
    phi = jr.gear_output(robot, theta, ccw)
    deflection = rest_link_angles(robot, theta, ccw, throw=False) - phi
    return phi + deflection, deflection


def _residual_fn(robot0, params: ParameterMap, theta, target_p, target_r, deflection, marker, weight_r, ccw,
                 rippled: tuple[int, ...] | None = None, q0=None, pose_weight=None, whiten=None):
    """Residual `fn(x, _)` in scaled variables `v = v0 + scale x`, its start `v0` and `scale`; each
    pose's position rows times its `whiten` (K, 3, 3) and all its rows times `sqrt(pose_weight)` (K,)
    where given.

    The model is `predict_pose` with its per-pose constants hoisted (`joint_angle_model`; `q0`,
    the initial joint angles of `rest_pose`, may be given). Its Jacobian is supplied per pose: for position rows
    and joint parameters from the joint screws (`position_jacobian`), else by reverse mode
    (3 or 6 outputs against the robot fields that `params` touches) chained with
    `d fields / d x`; either costs a few model evaluations instead of m forward passes.
    """
    v0 = params.get(robot0)
    scale = params.scales(robot0)
    orient = target_r is not None
    rippled = rippled_joints(robot0) if rippled is None else rippled
    full_ratio = any(f"u0_{j + 1}" in params.names for j in rippled)
    q0, q_pose = joint_angle_model(robot0, params, theta, deflection, ccw, rippled, q0)
    keys = tuple(dict.fromkeys(parse_name(n)[0] for n in params.names))

    def robot_of(fields):
        return eqx.tree_at(lambda r: tuple(getattr(r, k) for k in keys), robot0, tuple(fields[k] for k in keys))

    def fields_of(x):
        robot = params.set(robot0, v0 + scale * x)
        return {k: getattr(robot, k) for k in keys}

    def one_pose(fields, th, q0k, de, tp, tr, cw):
        robot = robot_of(fields)
        p, r = marker_pose(robot, q_pose(robot, th, q0k, de, cw), marker)
        res = (p - tp) / RESIDUAL_UNIT
        if orient:
            res = jnp.concatenate([res, weight_r * jr.rotation_error(tr, r) / RESIDUAL_UNIT])
        return res

    ccw_b = jnp.broadcast_to(jnp.asarray(ccw), theta.shape)
    root_w = jnp.ones(theta.shape[:-1]) if pose_weight is None else jnp.sqrt(pose_weight)

    def rows_of(out):  # (K, rows[, m]): whiten the 3 position rows of each pose, weigh all its rows
        if whiten is not None:
            out = jnp.concatenate([jnp.einsum("kij,kj...->ki...", whiten, out[:, :3]), out[:, 3:]], 1)
        return out * root_w.reshape((-1,) + (1,) * (out.ndim - 1))

    tr = target_r if orient else jnp.zeros(theta.shape[:-1] + (3, 3))
    axes = (None, 0, 0, 0, 0, 0, 0)
    data = (theta, q0, deflection, target_p, tr, ccw_b)

    @jax.custom_jvp
    def resid(x):
        return rows_of(jax.vmap(one_pose, axes)(fields_of(x), *data)).ravel()

    def one_jacobian(fields, th, q0k, de, tp, tr, cw):
        robot = robot_of(fields)
        q = q_pose(robot, th, q0k, de, cw)
        ratio = jr.gear_ratio(robot, q - de, cw) if full_ratio else robot.u0
        return position_jacobian(robot, params, q, th, ratio, marker)[1] * (scale / RESIDUAL_UNIT)

    @resid.defjvp
    def _resid_jvp(primals, tangents):
        (x,), (t,) = primals, tangents
        if orient or not analytic_names(params.names):  # autodiff: per pose, by the touched robot fields
            fields, dfields = jax.jvp(fields_of, (x,), (t,))
            jac = jax.vmap(jax.jacrev(one_pose), axes)(fields, *data)  # {key: (K, rows, *field)}
            out = sum(jnp.sum((jac[k] * dfields[k][None, None]).reshape(jac[k].shape[:2] + (-1,)), -1)
                      for k in keys)
            return resid(x), rows_of(out).ravel()
        jac = jax.vmap(one_jacobian, axes)(fields_of(x), *data)  # (K, 3, m), joint screws
        return resid(x), rows_of(jac @ t).ravel()

    return (lambda x, _: resid(x)), v0, scale


class ParameterEstimate(eqx.Module):
    """Free parameters estimated by LM, in the units of `ParameterMap`, for one robot or a fleet
    (leading axes `*b`), from n residuals."""

    value: Float[Array, "*b m"]
    """The parameters at the solution."""
    std: Float[Array, "*b m"]
    """Their standard errors (`sqrt(diag(covariance))`)."""
    covariance: Float[Array, "*b m m"]
    """`s^2 (J^T J)^{-1}`, `s^2` the noise estimate."""
    status: RESULTS
    """The solver's status; `rank_deficient` for a converged solve with a rank-deficient Jacobian,
    `nonfinite` for a non-finite solution."""
    steps: Int[Array, "*b"]
    """LM steps taken."""
    rank: Int[Array, "*b"]
    """Numerical rank of the scaled Jacobian."""
    residuals: Float[Array, "*b n"]
    """Residuals at the solution [m] (orientation rows in m-equivalent units), unweighted by the pose
    weights of a robust fit."""
    noise_variance: Float[Array, "*b"]
    """`s^2 = ||r||^2 / (n - m)` [m^2] of the weighted residuals."""
    jacobian: Float[Array, "*b n m"] | None = None
    """The Jacobian at the solution, residual mm per parameter unit (one robot only; None for a fleet)."""

    @property
    def converged(self) -> Bool[Array, "*b"]:
        """True where the solve converged (`status == RESULTS.successful`)."""
        return self.status == RESULTS.successful


def solve(
    robot0: jr.Robot,
    params: ParameterMap,
    theta: Float[Array, "K n"],
    positions: Float[Array, "K 3"],
    deflection: Float[Array, "K n"],
    marker: Float[Array, "3"],
    rotations: Float[Array, "K 3 3"] | None = None,
    weight_r: float | Float[Array, ""] = 1.0,
    ccw: bool | Bool[Array, "K n"] = False,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    max_steps: int = 100,
    rippled: tuple[int, ...] | None = None,
    prior_weight: Float[Array, " m"] | None = None,
    pose_weight: Float[Array, " K"] | None = None,
    whiten: Float[Array, "K 3 3"] | None = None,
    throw: bool = False,
    q0: Float[Array, "K n"] | None = None,
) -> ParameterEstimate:
    """LM solve for one robot; pure and jit/vmap-safe.

    `prior_weight`: maximum a posteriori with independent Gaussian priors on the deviations,
    entered as rows `prior_weight * x` (x: scaled deviation; weight = noise / prior std, in the
    residual's mm); `None` is plain least squares.

    `pose_weight`: the weight of each pose's squared residual (the robust losses' reweighting,
    `identification.core._robust`); `None` weights all alike. The returned residuals are unweighted, the
    noise variance and covariance those of the weighted rows. `whiten`: each pose's position rows times
    this matrix (`identification.core._noise`: an anisotropic tracker's `sigma Sigma_k^{-1/2}`), residuals too.

    `rippled`: the joints whose gears have ripple (`rippled_joints`; static), needed when `robot0`
    is traced (e.g. under `vmap`), else found from `robot0`; a free `u0` of a ripple-free gear then
    skips the Newton inversion. `q0`: the poses' link angles at rest in `robot0` (`rest_pose`), computed here
    unless given.

    **Returns:** `ParameterEstimate` with its `jacobian`. `throw`: raise the message of its status
    when it is not `successful` (also under `jit`).
    """
    fn_data, v0, scale = _residual_fn(robot0, params, theta, positions, rotations, deflection, marker, weight_r,
                                      ccw, rippled, q0, pose_weight=pose_weight, whiten=whiten)
    fn = fn_data if prior_weight is None else (lambda x, a: jnp.concatenate([fn_data(x, a), prior_weight * x]))
    x0 = jnp.zeros(len(params))
    sol = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=rtol, atol=atol), x0, max_steps=max_steps,
                             throw=False)
    x = sol.value
    r = fn_data(x, None)
    jx = jax.jacfwd(fn_data)(x, None)  # (n, m), in mm per scaled unit
    n, m = r.shape[0], x.shape[0]
    sigma2 = jnp.sum(r**2) / jnp.maximum(n - m, 1)
    j_all = jx if prior_weight is None else jnp.concatenate([jx, jnp.diag(prior_weight)])
    s = jnp.linalg.svd(j_all, compute_uv=False)
    rank = jnp.sum(s > 1e-10 * s[0])
    cov_x = sigma2 * jnp.linalg.inv(j_all.T @ j_all)
    cov = cov_x * scale[:, None] * scale[None, :]
    result = RESULTS.promote(sol.result)
    result = RESULTS.where(result == RESULTS.successful,
                           RESULTS.where(jnp.all(jnp.isfinite(x)),
                                         RESULTS.where(rank == m, RESULTS.successful, RESULTS.rank_deficient),
                                         RESULTS.nonfinite), result)
    if pose_weight is not None:
        r = _residual_fn(robot0, params, theta, positions, rotations, deflection, marker, weight_r, ccw, rippled,
                         q0, whiten=whiten)[0](x, None)
    out = ParameterEstimate(value=v0 + scale * x, std=jnp.sqrt(jnp.diag(cov)), covariance=cov, status=result,
                            steps=sol.stats["num_steps"], rank=rank, residuals=r * RESIDUAL_UNIT,
                            noise_variance=sigma2 * RESIDUAL_UNIT**2, jacobian=jx / scale)
    return check(result, out, throw)


_solve_jit = cached_program(solve, filter=True)
