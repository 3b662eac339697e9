"""Kinematic calibration of one robot (thesis 3.2.3, eq. 3.12): the `calibrate` workflow.

The Levenberg-Marquardt solve of a parameter set is `_solve`. By default the squared norms are replaced by a
robust loss of each pose's residual (Cauchy, by iteratively reweighted least squares,
`identification.core._robust`), so that gross tracker errors do not move the model; they are reported as
outliers. The parameter covariance is `s^2 (J^T W J)^{-1}` (`W` the final pose weights) with the noise estimate
`s^2 = ||r||^2 / (n - m)` over the `n` residuals of the poses within the outlier bound (all of them for
`loss="l2"`), `m` parameters. The default parameter set is fitted, reduced by backward elimination by BIC
(`_selection`) and the kept parameters fitted again.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

import jaxrobot as jr
from jaxrobot import RESULTS
from jaxrobot.internal import check
from jaxrobot.measurement import Poses, pose_arrays

from ..core import _robust as robust
from ..core._identifiability import (
    IdentifiabilityResult,
    ParameterCheck,
    analyse,
    check_parameters,
    default_analysis,
    default_set,
)
from ..core._noise import ALPHA, model_uncertainty, noise_model, noise_test, tracker_noise
from ..core._parameters import THESIS_PARAMETERS, ParameterMap, parse_name
from ..core._pose_checks import check_pose_units
from ..core._pose_selection import pose_jacobians
from ..core._robust import Outlier
from ._selection import ParameterSelection, select_parameters
from ._solve import (
    RESIDUAL_UNIT,
    ParameterEstimate,
    _residual_fn,
    _solve_jit,
    position_errors,
    rest_pose,
    rippled_joints,
)

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
    """The solve's status (`jaxrobot.status_name` gives its name, `jaxrobot.status_message` its message);
    `nonlinear_max_steps_reached` also where a robust loss's reweighting had not settled after `IRLS_STEPS` solves."""
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
    validation_spread: dict[tuple[str, ...], float] | None = None
    """[m] The RMS distance the covariance of the parameters gives the validation poses (linearised), for the
    fitted set and, where the `selection` set some aside, the whole default set: `{names: spread}` (None without
    validation poses)."""
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

    def uncertainty(self, source: str = "calibrate") -> jr.ModelUncertainty | None:
        """What the calibration leaves uncertain in `robot` (`jaxrobot.ModelUncertainty`, the robot file's
        `[uncertainty]`; `model_uncertainty`): `source` names the command. Where the `selection` set parameters
        aside, those stay uncertain too: at their start values they are off by their true deviations, which the
        data could not tell from zero, so the uncertainty is over the whole default set (the values of `robot`),
        its covariance averaged over the models of each parameter set aside by their BIC weights
        (`ParameterSelection.averaged_covariance`); None where no parameter was fitted."""
        sel = self.selection
        if sel is not None and sel.set_aside and sel.covariance is not None:
            names, cov = sel.candidates, sel.averaged_covariance()
            value = np.asarray(ParameterMap(sel.candidates).get(self.robot))
        elif self.names:
            names, value, cov = self.names, self.value, self.covariance
        else:
            return None
        spread = None if self.validation_spread is None else self.validation_spread.get(tuple(names))
        return model_uncertainty(names, value, cov, self.noise_estimate, self.chi2, self.dof, self.validation_after,
                                 spread, source)

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


@dataclasses.dataclass(frozen=True)
class _Fit:
    """One (robust) fit of a parameter set: the estimate, residuals (K, rows) [m], final pose weights (K,), the
    noise estimate [m] and the covariance scaled to it."""

    estimate: ParameterEstimate
    residuals: np.ndarray
    weights: np.ndarray
    noise: float
    covariance: np.ndarray


@dataclasses.dataclass(frozen=True)
class _Problem:
    """The constants of a calibration's fits: the start robot and its rippled joints, its K identification poses
    (motor angles, link angles at rest and gravity deflection in the start robot, measured positions and
    rotations, gear sets), the tracker (marker, noise, whitening), and the identification and validation poses
    together (`*_all`, the validation poses after the K) for the errors."""

    robot: jr.Robot
    rippled: tuple[int, ...]
    theta: jax.Array
    q: jax.Array
    deflection: jax.Array
    positions: np.ndarray
    rotations: jax.Array | None
    ccw: bool | np.ndarray
    marker: jax.Array
    sigma: float
    whiten: np.ndarray | None
    weight_r: jax.Array
    loss: str
    prior: np.ndarray | None
    max_steps: int
    throw: bool
    theta_all: jax.Array
    positions_all: np.ndarray
    q_all: jax.Array
    deflection_all: jax.Array
    ccw_all: bool | np.ndarray
    validated: bool

    @property
    def rows(self) -> int:
        return 3 if self.rotations is None else 6

    def _whiten(self):
        return None if self.whiten is None else jnp.asarray(self.whiten)

    def fit(self, params: ParameterMap) -> _Fit:
        """The fit of `params`: plain least squares, or iteratively reweighted for a robust loss."""
        robot, k, s_p = self.robot, self.theta.shape[0], self.sigma
        weight = None if self.prior is None else jnp.asarray(
            s_p / RESIDUAL_UNIT * np.asarray(params.scales(robot)) / self.prior)

        def fit(pose_w):
            out = _solve_jit(robot, params, self.theta, jnp.asarray(self.positions), self.deflection, self.marker,
                             self.rotations, self.weight_r, self.ccw, max_steps=self.max_steps,
                             rippled=self.rippled, prior_weight=weight,
                             pose_weight=None if self.loss == "l2" else jnp.asarray(pose_w), whiten=self._whiten(),
                             q0=self.q)
            resid = np.asarray(out.residuals).reshape(k, self.rows)
            return (out, resid), np.linalg.norm(resid, axis=-1) / s_p

        pose_w = np.ones(k)
        (out, resid), pose_w, settled = ((fit(pose_w)[0], pose_w, True) if self.loss == "l2"
                                         else robust.irls(fit, pose_w, self.loss, self.rows))
        result = robust.settled_status(out.status, settled)
        out = jax.tree.map(np.asarray, eqx.tree_at(lambda o: o.status, out, result))
        if self.prior is None:
            check_rank(out.jacobian, params)
        check(result, result, self.throw)
        noise = (float(np.sqrt(out.noise_variance)) if self.loss == "l2"
                 else robust.noise_estimate(resid, s_p, len(params)))
        return _Fit(out, resid, pose_w, noise, out.covariance * noise**2 / np.maximum(out.noise_variance, 1e-300))

    def start(self, params: ParameterMap) -> _Fit:
        """The start robot as the result (every parameter of `params` set aside): its residuals and pose weights."""
        k = self.theta.shape[0]
        r = _residual_fn(self.robot, params, self.theta, jnp.asarray(self.positions), self.rotations, self.deflection,
                         self.marker, self.weight_r, self.ccw, self.rippled, self.q,
                         whiten=self._whiten())[0](jnp.zeros(len(params)), None)
        resid = np.asarray(r).reshape(k, self.rows) * RESIDUAL_UNIT
        z = np.linalg.norm(resid, axis=-1) / self.sigma
        l2 = self.loss == "l2"
        pose_w = np.ones(k) if l2 else robust.irls(lambda w: (None, z), np.ones(k), self.loss, self.rows)[1]
        noise = float(np.sqrt(np.mean(resid**2))) if l2 else robust.noise_estimate(resid, self.sigma, 0)
        out = ParameterEstimate(value=np.zeros(0), std=np.zeros(0), covariance=np.zeros((0, 0)),
                                status=RESULTS.successful, steps=np.asarray(0), rank=np.asarray(0),
                                residuals=resid.ravel(), noise_variance=np.asarray(noise**2))
        return _Fit(out, resid, pose_w, noise, out.covariance)

    def result(self, params: ParameterMap | None, fit: _Fit, **fields) -> CalibrationResult:
        """The `CalibrationResult` of `fit` of `params` (None: every parameter set aside), with the errors of the
        identification and validation poses before and after and the chi-square test; `fields`: the others."""
        robot, out, k, s_p = self.robot, fit.estimate, self.theta.shape[0], self.sigma
        calibrated = robot if params is None else params.set(robot, jnp.asarray(out.value))
        err0, err1 = (position_errors(r, self.theta_all, self.positions_all, self.deflection_all, self.marker,
                                      self.ccw_all) for r in (robot, calibrated))
        chi2, dof, p_value = noise_test(fit.residuals, s_p, len(out.value), fit.weights > 0)
        val = self.validated
        return CalibrationResult(
            robot=calibrated, names=() if params is None else params.names, value=out.value,
            start=np.zeros(0) if params is None else np.asarray(params.get(robot)),
            std=np.sqrt(np.diag(fit.covariance)), covariance=fit.covariance, residuals=fit.residuals.ravel(),
            status=out.status, iterations=int(out.steps), noise_estimate=fit.noise, loss=self.loss,
            weights=fit.weights, outliers=robust.outliers(fit.residuals, s_p),
            outlier_bound=s_p * robust.outlier_bound(self.rows), errors_before=err0[:k], errors_after=err1[:k],
            validation_before=err0[k:] if val else None, validation_after=err1[k:] if val else None,
            prior_std=self.prior, chi2=float(chi2), dof=int(dof), p_value=float(p_value), **fields)

    def spread(self, sets: list[tuple[tuple[str, ...], np.ndarray]]) -> dict[tuple[str, ...], float] | None:
        """`CalibrationResult.validation_spread` of parameter sets `(names, covariance)` (None without validation
        poses): `sqrt(mean_k trace(J_k C J_k^T))` over the validation poses' position Jacobians `J_k`."""
        if not self.validated:
            return None
        q = np.asarray(self.q_all[self.theta.shape[0]:])
        out = {}
        for names, cov in sets:
            blocks = pose_jacobians(self.robot, ParameterMap(names), q, self.marker)
            out[tuple(names)] = float(np.sqrt(np.mean(np.einsum("kim,mn,kin->k", blocks, cov, blocks))))
        return out

    def check(self, analysis: IdentifiabilityResult, prior_std: dict | None) -> ParameterCheck:
        """`check_default` of the default set of `analysis` on these poses."""
        return check_default(self.robot, analysis, self.q, self.marker, self.whiten, float(self.weight_r), self.sigma,
                             prior_std)


def _problem(robot: jr.Robot, theta, positions, quaternions, ccw, validation, instruments: jr.Instruments, noise,
             marker, loss: str, prior, max_steps: int, throw: bool) -> _Problem:
    """The `_Problem` of `calibrate`'s checked poses: the link angles at rest and gravity deflection of the
    identification and validation poses in one evaluation, the noise model of the tracker `noise` at the measured
    positions."""
    s_p, white = noise_model(noise, positions, "instruments.tracker_noise")
    vt, vp, vccw = _validation_arrays(robot, validation)
    k = theta.shape[0]
    ccw_all = ccw if np.ndim(ccw) == 0 and not vccw.any() else np.concatenate(
        [np.broadcast_to(ccw, theta.shape), vccw])
    th_all = jnp.asarray(np.concatenate([theta, vt]))
    q_all, defl_all = rest_pose(robot, th_all, ccw_all)  # one evaluation for both sets
    rotations = None if quaternions is None else jr.quaternion_to_rotation(jnp.asarray(quaternions))
    return _Problem(robot, rippled_joints(robot), th_all[:k], q_all[:k], defl_all[:k], positions, rotations,
                    ccw if np.ndim(ccw) == 0 else ccw_all[:k], marker, s_p, white,
                    jnp.asarray(s_p / instruments.tracker_orientation_noise), loss, prior, max_steps, throw, th_all,
                    np.concatenate([positions, vp]), q_all, defl_all, ccw_all, validation is not None)


def _validation_arrays(robot: jr.Robot, validation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Motor angles (V, n), positions (V, 3) and gear sets (V, n) of `calibrate`'s `validation` (none: V = 0)."""
    if validation is None:
        return np.zeros((0, robot.n_joints)), np.zeros((0, 3)), np.zeros((0, robot.n_joints), bool)
    if isinstance(validation, Poses):
        validation = (validation.motor_angles, validation.positions) + (
            () if validation.ccw is None else (validation.ccw,))
    vt = _check_array(validation[0], (robot.n_joints,), "validation motor_angles", "rad")
    vp = _check_array(validation[1], (3,), "validation positions", "m")
    if vp.shape[0] != vt.shape[0]:
        raise ValueError(f"validation positions: expected {vt.shape[0]} rows, found {vp.shape[0]}")
    return vt, vp, np.broadcast_to(np.asarray(validation[2], bool) if len(validation) > 2 else False, vt.shape)


def calibrate(
    robot: jr.Robot,
    motor_angles: Float[Array, "K n"] | Poses,
    positions: Float[Array, "K 3"] | None = None,
    quaternions: Float[Array, "K 4"] | None = None,
    *,
    instruments: jr.Instruments,
    parameters: Sequence[str] | None = None,
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
    - `instruments`: the measurement setup (`jaxrobot.Instruments`, e.g. `jaxrobot.io.read_instruments(file)`):
      its `marker_offset` places the marker in the tool frame, its tracker noise (a laser tracker's whitens each
      pose's position residual) scales the robust loss and the noise test, its `tracker_orientation_noise` weighs
      orientation rows against position rows; a setting it lacks raises an error naming it.
    - `parameters`: free parameter names, fitted as given. Default: `default_parameters(robot)` for the
      measurement type (positions, or positions and orientations when `quaternions` are given), fitted
      together, then reduced by backward elimination while the BIC does not rise and the kept ones fitted
      again (`_selection`; the result's `selection` names both sets); `all_parameters=True` keeps the whole
      default set. `method="map"` fits the whole set too (its priors regularise it).
    - `ccw`: gear set of the approach direction (default `cw`). `validation`: `Poses`,
      `(motor_angles, positions)` or `(motor_angles, positions, ccw)`.
    - `limits`: `"flag"` lists poses beyond the joint limits in `beyond_limits`,
      `"raise"` rejects them.
    - `method`: `"lm"` plain least squares, or `"map"` maximum a posteriori with the tolerance
      priors `DEFAULT_PRIOR_STD` updated by `prior_std` (same keys); the result then carries each
      parameter's prior std and the fraction of its prior variance the data remove (`data_fraction`;
      the data determine it above `DATA_FRACTION`).
    - `loss`: `"cauchy"` (default) or `"huber"`, robust losses on each pose's residual norm in units of
      the tracker noise, by iteratively reweighted least squares (`identification.core._robust`: thresholds,
      outlier bound); `"l2"` plain least squares. Poses beyond the outlier bound are listed in
      `outliers` whichever the loss; the noise estimate leaves them out.

    Raises `ValueError` before solving for wrong shapes, NaN rows (named), fewer equations than
    parameters, unit mistakes (`check_pose_units`), a setting `instruments` lacks, and, with
    `limits="raise"`, poses beyond the joint limits (by row); after the solve, for a
    rank-deficient pose set (naming the unidentifiable directions). A solve that does not converge is
    returned with its `status` (a `jaxrobot.RESULTS`; `converged` False), never as success;
    `throw=True` raises its message instead (`RESULTS.error_if`).

    **Returns:** `CalibrationResult` (SI units; `identification.cli.calibration_report` gives the report dict).
    """
    motor_angles, positions, quaternions, ccw = pose_arrays(motor_angles, positions, quaternions, ccw)
    ccw = False if ccw is None else ccw
    marker = jnp.asarray(instruments.require("marker_offset", by="calibrate")[0], float)
    noise = tracker_noise(instruments, by="calibrate")
    robust.check_loss(loss)
    if method not in ("lm", "map"):
        raise ValueError(f"method: expected 'lm' or 'map', found {method!r}")
    checked = parameters is None and method == "lm"
    select = checked and not all_parameters
    analysis = None
    if parameters is None:
        _check_array(motor_angles, (robot.n_joints,), "motor_angles", "rad")
        _check_array(positions, (3,), "positions", "m")
        analysis = default_analysis(robot, orientation=quaternions is not None, marker=marker)
        parameters = default_set(analysis)
    params = ParameterMap(parameters)
    prior = prior_stds(robot, params, prior_std) if method == "map" else None
    theta, pos, quat, beyond = check_inputs(robot, params, motor_angles, positions, quaternions, limits, ccw)
    check_pose_units(robot, theta, pos, marker, "motor_angles/positions")
    problem = _problem(robot, theta, pos, quat, ccw, validation, instruments, noise, marker, loss, prior, max_steps,
                       throw)
    check_out = problem.check(analysis, prior_std) if checked else None
    params = params if check_out is None else ParameterMap(check_out.kept)
    fit, selection = problem.fit(params), None
    if select and fit.estimate.converged:
        selection = select_parameters(params.names, fit.estimate.value - np.asarray(params.get(robot)),
                                      fit.covariance, problem.rows * int(np.sum(fit.weights > 0)))
        if selection.kept and selection.set_aside:
            params = ParameterMap(selection.kept)
            fit = problem.fit(params)
        elif not selection.kept:
            fit, params = problem.start(params), None
    sets = [] if params is None else [(params.names, fit.covariance)]
    if selection is not None and selection.set_aside:
        sets.append((selection.candidates, selection.averaged_covariance()))
    return problem.result(params, fit, beyond_limits=tuple(beyond), method=method, selection=selection,
                          parameter_check=check_out, validation_spread=problem.spread(sets))


def check_default(
    robot: jr.Robot, analysis: IdentifiabilityResult, q: Float[Array, "K n"], marker, whiten, weight_r: float,
    noise: float, prior_std: dict | None = None,
) -> ParameterCheck:
    """`check_parameters` of the default set of `analysis` (`default_analysis`, `default_set`) on a calibration's
    own poses (the link angles at rest `q` of `rest_pose`; positions, and orientations where `analysis` has
    them): the Jacobian of every candidate (`analysis.names`) at the start robot with the rows of the fit
    (position rows times `whiten` (K, 3, 3) where given, orientation rows times `weight_r`), each parameter
    against its tolerance prior (`prior_stds`); the geometry stage's left-out candidates are reported with it."""
    candidates, names, orientation = analysis.names, default_set(analysis), analysis.orientation
    q = np.asarray(q)
    blocks = pose_jacobians(robot, ParameterMap(candidates), q, marker, orientation)
    b = blocks[..., [candidates.index(n) for n in names]]
    pos = b[:, :3] if whiten is None else np.einsum("kij,kjm->kim", np.asarray(whiten), b[:, :3])
    rows = np.concatenate([pos, weight_r * b[:, 3:]], 1) if orientation else pos
    params = ParameterMap(names)
    return check_parameters(rows.reshape(-1, len(names)), names, noise, prior_stds(robot, params, prior_std),
                            len(q), analysis=analysis, candidates=candidates)


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
