"""Kinematic calibration by Levenberg-Marquardt (thesis 3.2.3, eq. 3.12).

`min_v sum_i ||p_e(v, theta_i) - p_{e,m,i}||^2` over the free parameters `v`, with the forward
model of `predict_pose` (motor angles -> `Xi^{-1}` -> plus gravity deflection -> marker), solved
with `optx.least_squares` + `optx.LevenbergMarquardt` in scaled variables (1 mm, 1 mrad, 1e-3
of a gear ratio). By default the squared norms are replaced by a robust loss of each pose's residual
(Cauchy, by iteratively reweighted least squares, `identification.core._robust`), so that gross tracker
errors do not move the model; they are reported as outliers. The parameter covariance is
`s^2 (J^T W J)^{-1}` (`W` the final pose weights) with the noise estimate `s^2 = ||r||^2 / (n - m)`
over the `n` residuals of the poses within the outlier bound (all of them for `loss="l2"`), `m`
parameters. The default parameter set is fitted, reduced by backward elimination by BIC (`_selection`)
and the kept parameters fitted again.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

import jaxrobot as jr
from jaxrobot import RESULTS
from jaxrobot.internal import cached_program, check
from jaxrobot.measurement import Poses, marker_pose, pose_arrays

from ..core import _robust as robust
from ..core._forward import (
    analytic_names,
    joint_angle_model,
    position_jacobian,
    rippled_joints,
)
from ..core._identifiability import (
    ParameterCheck,
    analyse,
    check_parameters,
    default_analysis,
    default_parameters,
    kinematic_parameters,
)
from ..core._noise import ALPHA, noise_model, noise_test
from ..core._parameters import THESIS_PARAMETERS, ParameterMap, parse_name, predict_pose, rest_deflection
from ..core._pose_checks import check_pose_units
from ..core._pose_selection import default_marker, pose_jacobians
from ..core._robust import Outlier
from ._selection import ParameterSelection, select_parameters

DEFAULT_PARAMETERS = THESIS_PARAMETERS + ("offset1", "offset2", "offset4", "offset5", "offset6", "d1",
                                          "d6", "a6", "beta2")
"""The Racer-7's default set, what `default_parameters` computes for it from marker positions:
the thesis' 17 (Table 3.5) plus what else the identifiability analysis finds identifiable
from marker positions with the bench's marker offset (26): offsets 1, 2, 4, 5, 6 (offset 3 is
`beta3 - a3 d4`), d1 (the base frame is known), d6 and a6 (the marker sits off the joint-6
axis; `alpha6` is then a combination of d6, a6 and offset6), and `beta2`, the tilt of axis 3 out of the
plane of the parallel axes 2 and 3 (`kinematic_parameters`)."""

DEFAULT_PRIOR_STD = {"a": 1e-3, "d": 1e-3, "alpha": 1e-3, "beta": 1e-3, "offset": 2e-3, "u0": 1e-3,
                     "tool_xyz": 1e-3, "tool_rpy": 1e-3, "base_xyz": 1e-3, "base_rpy": 1e-3}
"""Tolerance priors of the maximum-a-posteriori calibration (std of a deviation from the start
robot): lengths 1 mm, link angles 1 mrad, joint zero offsets 2 mrad, gear ratios 1e-3 relative,
tool/base 1 mm and 1 mrad. A few times the manufacturing deviations the thesis identifies for
the Racer-7 (Table 3.8: up to 0.64 mm, 0.84 mrad, wrist ratios 5e-4 relative), so the data
override them where they can. Overridden per field by the robot file's `[calibration] prior_std`
(`a_m`, `d_m`, `alpha_rad`, `beta_rad`, `offset_rad`, `u0_relative`, `tool_m`, `tool_rad`,
`base_m`, `base_rad`)."""
PRIOR_KEYS = {"a_m": "a", "d_m": "d", "alpha_rad": "alpha", "beta_rad": "beta", "offset_rad": "offset",
              "u0_relative": "u0", "tool_m": "tool_xyz", "tool_rad": "tool_rpy", "base_m": "base_xyz",
              "base_rad": "base_rpy"}
"""Keys of `[calibration] prior_std` in a robot file -> keys of `DEFAULT_PRIOR_STD`."""
DATA_FRACTION = 0.5
"""A parameter counts as determined by the data when they remove more than this fraction of its
prior variance (`1 - posterior / prior variance`), else by the prior."""

RESIDUAL_UNIT = 1e-3
"""Residuals are solved in mm (and orientation in units of the position/orientation noise ratio)."""


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
def _deflection(robot, theta, ccw):
    return rest_deflection(robot, theta, ccw)


def _residual_fn(robot0, params: ParameterMap, theta, target_p, target_r, deflection, marker, weight_r, ccw,
                 rippled: tuple[int, ...] | None = None, q0=None, pose_weight=None, whiten=None):
    """Residual `fn(x, _)` in scaled variables `v = v0 + scale x`, its start `v0` and `scale`; each
    pose's position rows times its `whiten` (K, 3, 3) and all its rows times `sqrt(pose_weight)` (K,)
    where given.

    The model is `predict_pose` with its per-pose constants hoisted (`_model`; `q0`,
    the initial joint angles, may be given). Its Jacobian is supplied per pose: for position rows
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
    skips the Newton inversion.

    **Returns:** `ParameterEstimate` with its `jacobian`. `throw`: raise the message of its status
    when it is not `successful` (also under `jit`).
    """
    fn_data, v0, scale = _residual_fn(robot0, params, theta, positions, rotations, deflection, marker, weight_r,
                                      ccw, rippled, pose_weight=pose_weight, whiten=whiten)
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
                         whiten=whiten)[0](x, None)
    out = ParameterEstimate(value=v0 + scale * x, std=jnp.sqrt(jnp.diag(cov)), covariance=cov, status=result,
                            steps=sol.stats["num_steps"], rank=rank, residuals=r * RESIDUAL_UNIT,
                            noise_variance=sigma2 * RESIDUAL_UNIT**2, jacobian=jx / scale)
    return check(result, out, throw)


_solve_jit = cached_program(solve, filter=True)


@dataclasses.dataclass(frozen=True)
class CalibrationResult:
    """Result of `calibrate` in SI units (m, rad; gear ratios and scales dimensionless;
    `identification.cli` turns it into tables and the JSON). `m` free parameters, `K` identification poses."""

    robot: jr.Robot
    """The calibrated robot."""
    names: tuple[str, ...]
    """The free parameters (names and units of `ParameterMap`)."""
    value: np.ndarray
    """(m,) identified values."""
    start: np.ndarray
    """(m,) their values in the start robot."""
    std: np.ndarray
    """(m,) standard errors."""
    covariance: np.ndarray
    """(m, m) covariance of `value`."""
    residuals: np.ndarray
    """[m] data residuals at the solution (3 per pose, plus the orientation rows scaled by the
    noise ratio when orientations are given), unweighted by the robust loss."""
    status: RESULTS
    """The solve's status (`jaxrobot.status_name` gives its name, `jaxrobot.status_message` its message)."""
    iterations: int
    """Levenberg-Marquardt steps."""
    noise_estimate: float
    """[m] noise per axis estimated from the residuals of the poses within the outlier bound (their
    RMS with the m free parameters' degrees of freedom removed); it scales `covariance`."""
    loss: str
    """The loss of the fit (`"cauchy"`, `"huber"` or `"l2"`)."""
    weights: np.ndarray
    """(K,) the final weight of each pose's squared residual (1 for `"l2"`)."""
    outliers: tuple[Outlier, ...]
    """The identification poses whose residual norm exceeds `outlier_bound`, by row."""
    outlier_bound: float
    """[m] the residual norm above which a pose is reported as an outlier."""
    errors_before: np.ndarray
    """(K,) [m] model-measurement distance per identification pose with the start robot."""
    errors_after: np.ndarray
    """(K,) [m] the same with the calibrated robot."""
    validation_before: np.ndarray | None
    """[m] the distances of the validation poses with the start robot (None without)."""
    validation_after: np.ndarray | None
    """[m] the same with the calibrated robot (None without)."""
    beyond_limits: tuple[dict, ...]
    """The poses beyond the joint limits ({row, joint, q_deg, limits_deg})."""
    method: str
    """`"lm"` or `"map"`."""
    prior_std: np.ndarray | None
    """(m,) the MAP priors (None for `method="lm"`)."""
    chi2: float
    """Chi-square of the tracker's residuals at the solution against the stated noise, `sum r^2 / sigma^2` over
    the poses within the outlier bound (all for `loss="l2"`; whitened for a `TrackerNoise`; orientation rows in
    units of their own noise)."""
    dof: int
    """Its degrees of freedom: the residuals of those poses less the free parameters."""
    p_value: float
    """Probability that the tracker's noise alone exceeds `chi2` (`consistent` above `ALPHA`)."""
    selection: ParameterSelection | None = None
    """Which parameters of the default set were kept, which set aside, and by what criterion (`_selection`);
    None where none was selected (`parameters` given, `method="map"`, `all_parameters=True`, or a full-set
    fit that did not converge)."""
    parameter_check: ParameterCheck | None = None
    """How the default set came about (`method="lm"` without `parameters`): the candidates of the chain, those
    left out by the geometry and those dropped on these poses by rank or conditioning, with the reasons
    (`identification.core._identifiability.check_parameters`); None where `parameters` were given or for MAP."""

    @property
    def consistent(self) -> bool:
        """Whether the residuals agree with the stated tracker noise (the chi-square test at `ALPHA`)."""
        return bool(self.p_value > ALPHA)

    @property
    def converged(self) -> bool:
        """True only for status `successful`."""
        return bool(self.status == RESULTS.successful)

    @property
    def delta(self) -> np.ndarray:
        """Identified deviations from the start robot."""
        return self.value - self.start

    @property
    def residual_rms(self) -> float:
        """RMS of the residuals at the solution [m]."""
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def data_fraction(self) -> np.ndarray | None:
        """Fraction of each prior variance the data remove (MAP; `DATA_FRACTION` splits data from prior)."""
        return None if self.prior_std is None else 1.0 - self.std**2 / self.prior_std**2


def _check_array(x, shape_tail: tuple, field: str, unit: str) -> np.ndarray:
    a = np.asarray(x, float)
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail:
        raise ValueError(f"{field}: expected shape (K, {', '.join(map(str, shape_tail))}) in {unit}, "
                         f"found {a.shape}")
    bad = np.nonzero(~np.isfinite(a.reshape(a.shape[0], -1)).all(1))[0]
    if bad.size:
        raise ValueError(f"{field}: NaN/inf in rows {bad.tolist()} (0-based pose index); remove these poses")
    return a


def check_inputs(
    robot0: jr.Robot, params: ParameterMap, theta, positions, quaternions=None, limits: str = "flag",
    ccw=False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list]:
    """Validate shapes, NaN rows, counts and joint limits before any solve (see `calibrate`)."""
    theta = _check_array(theta, (robot0.n_joints,), "motor_angles", "rad")
    positions = _check_array(positions, (3,), "positions", "m")
    if positions.shape[0] != theta.shape[0]:
        raise ValueError(f"positions: expected one row per pose ({theta.shape[0]}), found {positions.shape[0]}")
    if quaternions is not None:
        quaternions = _check_array(quaternions, (4,), "quaternions", "(qx, qy, qz, qw)")
        if quaternions.shape[0] != theta.shape[0]:
            raise ValueError(f"quaternions: expected {theta.shape[0]} rows, found {quaternions.shape[0]}")
    rows = 3 + (3 if quaternions is not None else 0)
    if theta.shape[0] * rows < len(params):
        raise ValueError(f"motor_angles: {theta.shape[0]} poses give {theta.shape[0] * rows} equations for "
                         f"{len(params)} parameters {list(params.names)}; need at least "
                         f"{-(-len(params) // rows)} poses (better several times more)")
    if limits not in ("flag", "raise"):
        raise ValueError(f"limits: expected 'flag' or 'raise', found {limits!r}")
    q = np.asarray(jr.gear_output(robot0, jnp.asarray(theta), ccw))
    lo, hi = np.asarray(robot0.q_min), np.asarray(robot0.q_max)
    out = []
    for k, j in zip(*np.nonzero((q < lo) | (q > hi))):
        out.append({"row": int(k), "joint": int(j) + 1, "q_deg": float(np.rad2deg(q[k, j])),
                    "limits_deg": [float(np.rad2deg(lo[j])), float(np.rad2deg(hi[j]))]})
    if out and limits == "raise":
        txt = "; ".join(f"row {o['row']}: joint {o['joint']} at {o['q_deg']:.2f} deg outside "
                        f"[{o['limits_deg'][0]:.0f}, {o['limits_deg'][1]:.0f}]" for o in out[:20])
        raise ValueError(f"motor_angles: poses beyond the joint limits (0-based rows): {txt}")
    return theta, positions, quaternions, out


def check_rank(jac: np.ndarray, params: ParameterMap) -> None:
    """Raise if the pose set cannot identify all parameters, naming the unidentifiable
    directions (SVD + pivoted QR of the column-scaled Jacobian)."""
    res = analyse(np.asarray(jac)[None], params.names)
    if res.rank < len(params):
        deps = "; ".join(
            f"{n} ~ " + (" + ".join(f"{c:+.3g}*{k}" for k, c in d.items()) if d else "no effect")
            for n, d in res.dependencies.items())
        raise ValueError(f"pose set is rank deficient: rank {res.rank} for {len(params)} parameters; "
                         f"unidentifiable directions: {deps}. Remove these parameters or add poses "
                         f"that move the joints involved")


def calibrate(
    robot: jr.Robot,
    motor_angles: Float[Array, "K n"] | Poses,
    positions: Float[Array, "K 3"] | None = None,
    quaternions: Float[Array, "K 4"] | None = None,
    *,
    parameters: Sequence[str] | None = None,
    marker: Float[Array, "3"] | None = None,
    position_noise: float | None = None,
    orientation_noise: float | None = None,
    ccw: bool | Bool[Array, "K n"] | None = None,
    validation: tuple | Poses | None = None,
    limits: str = "flag",
    max_steps: int = 100,
    method: str = "lm",
    prior_std: dict | None = None,
    loss: str = "cauchy",
    all_parameters: bool = False,
    throw: bool = False,
) -> CalibrationResult:
    """Calibrate the kinematic parameters from tracker measurements (thesis 3.2.3, eq. 3.12).

    **Arguments:**
    - `robot`: the initial (nominal) robot; also supplies the gravity deflection model.
    - `motor_angles` (K, n) rad at rest; `positions` (K, 3) m measured marker positions;
      `quaternions` (K, 4) optional measured orientation (qx, qy, qz, qw); or `Poses` as `motor_angles`
      (then none of `positions`, `quaternions`, `ccw`: they come from the `Poses`).
    - `parameters`: free parameter names, fitted as given. Default: `default_parameters(robot)` for the
      measurement type (positions, or positions and orientations when `quaternions` are given), fitted
      together, then reduced by backward elimination while the BIC does not rise and the kept ones fitted
      again (`_selection`; the result's `selection` names both sets); `all_parameters=True` keeps the whole
      default set. `method="map"` fits the whole set too (its priors regularise it).
    - `marker`: marker offset in the tool frame [m] (default: the toml `[sensors]`).
    - `position_noise`, `orientation_noise`: stds that weight orientation rows against
      position rows (defaults: the toml tracker noise and 0.05 deg) and scale the robust loss;
      `position_noise` may be a laser tracker's `TrackerNoise` (`identification.core._noise`: std along and
      across the line of sight), whose covariance then whitens each pose's position residual.
    - `ccw`: gear set of the approach direction (default `cw`). `validation`: `Poses`,
      `(motor_angles, positions)` or `(motor_angles, positions, ccw)`.
    - `limits`: `"flag"` lists poses beyond the joint limits in `beyond_limits`,
      `"raise"` rejects them.
    - `method`: `"lm"` plain least squares, or `"map"` maximum a posteriori with the tolerance
      priors `DEFAULT_PRIOR_STD` updated by `prior_std` (same keys); the result then carries each
      parameter's prior std and the fraction of its prior variance the data remove (`data_fraction`;
      the data determine it above `DATA_FRACTION`).
    - `loss`: `"cauchy"` (default) or `"huber"`, robust losses on each pose's residual norm in units of
      `position_noise`, by iteratively reweighted least squares (`identification.core._robust`: thresholds,
      outlier bound); `"l2"` plain least squares. Poses beyond the outlier bound are listed in
      `outliers` whichever the loss; the noise estimate leaves them out.

    Raises `ValueError` before solving for wrong shapes, NaN rows (named), fewer equations than
    parameters, unit mistakes (`check_pose_units`), and, with
    `limits="raise"`, poses beyond the joint limits (by row); after the solve, for a
    rank-deficient pose set (naming the unidentifiable directions). A solve that does not converge is
    returned with its `status` (a `jaxrobot.RESULTS`; `converged` False), never as success;
    `throw=True` raises its message instead (`RESULTS.error_if`).

    **Returns:** `CalibrationResult` (SI units; `identification.cli.calibration_report` gives the report dict).
    """
    from jaxrobot.bench import ORIENTATION_NOISE_RAD

    motor_angles, positions, quaternions, ccw = pose_arrays(motor_angles, positions, quaternions, ccw)
    ccw = False if ccw is None else ccw
    if isinstance(validation, Poses):
        validation = (validation.motor_angles, validation.positions) + (
            () if validation.ccw is None else (validation.ccw,))
    marker = jnp.asarray(default_marker() if marker is None else marker, float)
    select = parameters is None and method == "lm" and not all_parameters
    checked = parameters is None and method == "lm"
    if parameters is None:
        _check_array(motor_angles, (robot.n_joints,), "motor_angles", "rad")
        _check_array(positions, (3,), "positions", "m")
        parameters = default_parameters(robot, orientation=quaternions is not None, marker=marker)
    params = ParameterMap(parameters)
    robust.check_loss(loss)
    if method not in ("lm", "map"):
        raise ValueError(f"method: expected 'lm' or 'map', found {method!r}")
    prior = None
    if method == "map":
        prior = prior_stds(robot, params, prior_std)
    theta, pos, quat, beyond = check_inputs(robot, params, motor_angles, positions, quaternions, limits, ccw)
    check_pose_units(robot, theta, pos, marker, "motor_angles/positions")
    sensors = jr.read_description(None)["sensors"]
    s_p, white = noise_model(sensors["tracker_position_noise_m"] if position_noise is None else position_noise,
                             pos, "position_noise")
    s_r = ORIENTATION_NOISE_RAD if orientation_noise is None else orientation_noise
    rot = None if quat is None else jr.quaternion_to_rotation(jnp.asarray(quat))
    w_r = jnp.asarray(s_p / s_r)
    if validation is not None:
        vt = _check_array(validation[0], (robot.n_joints,), "validation motor_angles", "rad")
        vp = _check_array(validation[1], (3,), "validation positions", "m")
        if vp.shape[0] != vt.shape[0]:
            raise ValueError(f"validation positions: expected {vt.shape[0]} rows, found {vp.shape[0]}")
        vccw = np.broadcast_to(np.asarray(validation[2], bool) if len(validation) > 2 else False, vt.shape)
    else:
        vt, vp = np.zeros((0, robot.n_joints)), np.zeros((0, 3))
        vccw = np.zeros(vt.shape, bool)
    k = theta.shape[0]
    ccw_all = ccw if np.ndim(ccw) == 0 and not vccw.any() else np.concatenate(
        [np.broadcast_to(ccw, theta.shape), vccw])
    th_all = jnp.asarray(np.concatenate([theta, vt]))
    defl_all = _deflection(robot, th_all, ccw_all)  # one evaluation for both sets
    th, defl = th_all[:k], defl_all[:k]
    ccw_id = ccw if np.ndim(ccw) == 0 else ccw_all[:k]
    rows = 3 if rot is None else 6
    check_out = None
    if checked:
        check_out = check_default(robot, params.names, th, defl, marker, rot is not None, white, float(w_r), s_p,
                                  prior_std, ccw_id)
        params = ParameterMap(check_out.kept)

    def fit_set(params):  # the (robust) fit of one parameter set: estimate, residuals (K, rows) [m], pose weights
        weight = None if prior is None else jnp.asarray(s_p / RESIDUAL_UNIT * np.asarray(params.scales(robot)) / prior)

        def fit(pose_w):
            out = _solve_jit(robot, params, th, jnp.asarray(pos), defl, marker, rot, w_r, ccw_id, max_steps=max_steps,
                             rippled=rippled_joints(robot), prior_weight=weight,
                             pose_weight=None if loss == "l2" else jnp.asarray(pose_w),
                             whiten=None if white is None else jnp.asarray(white))
            resid = np.asarray(out.residuals).reshape(k, rows)
            return (out, resid), np.linalg.norm(resid, axis=-1) / s_p

        pose_w = np.ones(k)
        (out, resid), pose_w = (fit(pose_w)[0], pose_w) if loss == "l2" else robust.irls(fit, pose_w, loss, rows)
        result = out.status
        out = jax.tree.map(np.asarray, out)
        if prior is None:
            check_rank(out.jacobian, params)
        check(result, result, throw)
        noise = float(np.sqrt(out.noise_variance)) if loss == "l2" else robust.noise_estimate(resid, s_p, len(params))
        return out, resid, pose_w, noise, out.covariance * noise**2 / np.maximum(out.noise_variance, 1e-300)

    out, resid, pose_w, noise, cov = fit_set(params)
    selection = None
    if select and out.converged:
        selection = select_parameters(params.names, out.value - np.asarray(params.get(robot)), cov,
                                      rows * int(np.sum(pose_w > 0)))
        if selection.kept and selection.set_aside:
            params = ParameterMap(selection.kept)
            out, resid, pose_w, noise, cov = fit_set(params)
        elif not selection.kept:  # every parameter set aside: the start robot, its residuals and weights
            r = _residual_fn(robot, params, th, jnp.asarray(pos), rot, defl, marker, w_r, ccw_id,
                             whiten=None if white is None else jnp.asarray(white))[0](jnp.zeros(len(params)), None)
            resid = np.asarray(r).reshape(k, rows) * RESIDUAL_UNIT
            z = np.linalg.norm(resid, axis=-1) / s_p
            pose_w = np.ones(k) if loss == "l2" else robust.irls(lambda w: (None, z), np.ones(k), loss, rows)[1]
            noise = float(np.sqrt(np.mean(resid**2))) if loss == "l2" else robust.noise_estimate(resid, s_p, 0)
            out = ParameterEstimate(value=np.zeros(0), std=np.zeros(0), covariance=np.zeros((0, 0)),
                                    status=RESULTS.successful, steps=np.asarray(0), rank=np.asarray(0),
                                    residuals=resid.ravel(), noise_variance=np.asarray(noise**2))
            cov, params = out.covariance, None
    calibrated = robot if params is None else params.set(robot, jnp.asarray(out.value))
    p_all = np.concatenate([pos, vp])
    err0 = position_errors(robot, th_all, p_all, defl_all, marker, ccw_all)
    err1 = position_errors(calibrated, th_all, p_all, defl_all, marker, ccw_all)
    val = validation is not None
    chi2, dof, p_value = noise_test(resid, s_p, len(out.value), pose_w > 0)
    return CalibrationResult(
        robot=calibrated, names=() if params is None else params.names, value=out.value,
        start=np.zeros(0) if params is None else np.asarray(params.get(robot)),
        std=np.sqrt(np.diag(cov)), covariance=cov, residuals=resid.ravel(),
        status=out.status, iterations=int(out.steps), noise_estimate=noise, loss=loss,
        weights=pose_w, outliers=robust.outliers(resid, s_p), outlier_bound=s_p * robust.outlier_bound(rows),
        errors_before=err0[:k], errors_after=err1[:k],
        validation_before=err0[k:] if val else None, validation_after=err1[k:] if val else None,
        beyond_limits=tuple(beyond), method=method, prior_std=prior, chi2=float(chi2), dof=int(dof),
        p_value=float(p_value), selection=selection, parameter_check=check_out)


def check_default(
    robot: jr.Robot, names: Sequence[str], theta, deflection, marker, orientation: bool, whiten, weight_r: float,
    noise: float, prior_std: dict | None = None, ccw=False,
) -> ParameterCheck:
    """`check_parameters` of the default set `names` on a calibration's own poses (motor angles `theta` (K, n),
    their gravity `deflection`), the Jacobian of every candidate (`kinematic_parameters`) at the start robot with
    the rows of the fit (position rows times `whiten` (K, 3, 3) where given, orientation rows times `weight_r`),
    each parameter against its tolerance prior (`prior_stds`); the geometry stage's left-out candidates are
    reported with it."""
    candidates = kinematic_parameters(robot)
    q = np.asarray(jr.gear_output(robot, jnp.asarray(theta), ccw) + jnp.asarray(deflection))
    blocks = pose_jacobians(robot, ParameterMap(candidates), q, marker, orientation)
    b = blocks[..., [candidates.index(n) for n in names]]
    pos = b[:, :3] if whiten is None else np.einsum("kij,kjm->kim", np.asarray(whiten), b[:, :3])
    rows = np.concatenate([pos, weight_r * b[:, 3:]], 1) if orientation else pos
    params = ParameterMap(names)
    return check_parameters(rows.reshape(-1, len(names)), names, noise, prior_stds(robot, params, prior_std),
                            len(q), analysis=default_analysis(robot, orientation=orientation, marker=marker),
                            candidates=candidates)


def map_parameters(parameters: Sequence[str], n_joints: int) -> tuple[str, ...]:
    """The free set of a MAP calibration: `parameters` plus every joint offset and basic gear ratio,
    including those identifiable only in combination (offset 3 ~ beta3 - a3 d4; the prior splits
    the combination) and the ratios a gear identification leaves uncertain to ~1e-4."""
    extra = [f"{k}{j}" for k in ("offset", "u0_") for j in range(1, n_joints + 1)]
    return tuple(parameters) + tuple(n for n in extra if n not in parameters)


def prior_stds(robot: jr.Robot, params: ParameterMap, overrides: dict | None = None) -> np.ndarray:
    """Prior std of every free parameter (`DEFAULT_PRIOR_STD` updated by `overrides`; `u0` relative)."""
    table = dict(DEFAULT_PRIOR_STD)
    for key, value in (overrides or {}).items():
        if key not in table:
            raise ValueError(f"prior_std: unknown key {key!r}; expected one of {sorted(table)}")
        if not float(value) > 0:
            raise ValueError(f"prior_std.{key}: expected a std > 0, found {value}")
        table[key] = float(value)
    out = []
    for n in params.names:
        field, comp = parse_name(n)
        if field == "u0":
            out.append(table["u0"] * float(robot.u0[comp]))
        elif field in ("tool", "base"):
            out.append(table[f"{field}_{'xyz' if comp in ('x', 'y', 'z') else 'rpy'}"])
        else:
            out.append(table[field])
    return np.asarray(out)
