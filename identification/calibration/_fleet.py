"""Kinematic calibration of a fleet: thousands of robots in one call (thesis 3.2.3 at scale).

Every robot has its own poses and measurements; all robots are solved together by one
batch-first Levenberg-Marquardt loop (`_batched_lm`, in chunks of `CHUNK` robots, on the model of
`_solve._residual_fn` with its joint-screw Jacobian evaluated batch-last over robots and
poses, `_solve.position_jacobian`), each robot stopping on its own tolerances. The
fleet axis is sharded across all devices with `jax.sharding` (a 1-D mesh named `"fleet"`,
`shard_map`: each device runs its own LM loop on its own robots, no communication), so that the
same call uses one CPU, several GPUs, or several processes and hosts under `jax.distributed`
(`jaxrobot.internal.initialize_processes`): each process passes only its own robots, the global arrays
are assembled from the processes' rows (`jaxrobot.internal.shard_rows`) and the results gathered back.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec
from jaxtyping import Array, Bool, Float

import jaxrobot as jr
from jaxrobot import RESULTS
from jaxrobot.internal import backend_kind, check, gather_array, gather_rows, shard_rows, where
from jaxrobot.measurement import Poses, pose_arrays, rest_link_angles

from ..core import _robust as robust
from ..core._batched_lm import LMConfig, batched_lm, covariance, map_chunks
from ..core._identifiability import ParameterCheck, default_analysis, default_set
from ..core._noise import ALPHA, model_uncertainty, noise_model, noise_test, tracker_noise
from ..core._parameters import ParameterMap
from ._calibrate import _check_array, check_default
from ._solve import (
    RESIDUAL_UNIT,
    ParameterEstimate,
    _residual_fn,
    analytic_names,
    joint_angle_model,
    position_jacobian,
    rest_pose,
    rippled_joints,
)


@dataclasses.dataclass(frozen=True)
class FleetResult:
    """Result of `calibrate_fleet`, per robot along the leading axis R (`m` free parameters, `K` poses)."""

    robot: jr.Robot
    """The calibrated fleet (a `Robot` pytree with leading axis R)."""
    value: np.ndarray
    """(R, m) identified values (units of `ParameterMap`)."""
    std: np.ndarray
    """(R, m) standard errors."""
    covariance: np.ndarray
    """(R, m, m) covariances."""
    converged: np.ndarray
    """(R,) True where the status is `successful`."""
    status: RESULTS
    """(R,) `successful`, `nonlinear_max_steps_reached` (the LM after `max_steps`, or a robust loss's reweighting
    not settled after `IRLS_STEPS` solves), `nonfinite`, `rank_deficient` or `inconsistent` (converged, but the
    residuals fail the chi-square test against the stated noise: `p_value` at or below `inconsistent_below`)
    (names by `jaxrobot.status_name`)."""
    iterations: np.ndarray
    """(R,) Levenberg-Marquardt steps."""
    rank: np.ndarray
    """(R,) numerical rank of the Jacobian."""
    rms_m: np.ndarray
    """(R,) [m] RMS of the residuals."""
    residuals: np.ndarray
    """(R, 3K) [m] model minus measurement at the solution (unweighted by the robust loss; whitened by
    each pose's covariance for a `TrackerNoise`)."""
    names: tuple[str, ...]
    """The free parameters."""
    n_devices: int
    """Devices the fleet was sharded over."""
    loss: str
    """The loss of the fit (`"cauchy"`, `"huber"` or `"l2"`, as in `calibrate`)."""
    noise_estimate: np.ndarray
    """(R,) [m] per-axis noise estimated from each robot's residuals (those of its poses within the
    outlier bound, as in `calibrate`); it scales `covariance`."""
    outliers: tuple[tuple[robust.Outlier, ...], ...]
    """Per robot, its poses whose residual norm exceeds the outlier bound (`calibrate`'s)."""
    chi2: np.ndarray
    """(R,) the tracker's chi-square: `sum r^2 / sigma^2` of the residuals of the poses the robust loss kept (all
    for `l2`) against the stated noise `sigma` (`identification.core._noise.noise_test`, as in `diagnose`)."""
    dof: np.ndarray
    """(R,) its degrees of freedom, 3 K' - m over the K' poses kept."""
    p_value: np.ndarray
    """(R,) probability that noise alone exceeds `chi2`."""
    inconsistent_below: float
    """`identification.core._noise.ALPHA / R`: the p-value at or below which a robot is `inconsistent`, so
    that noise alone marks any robot of a clean fleet with probability at most `ALPHA` (Bonferroni)."""
    parameter_check: ParameterCheck | None = None
    """How the default set came about (without `parameters`): the chain's candidates, those left out by the
    geometry and those dropped by rank or conditioning on the first robot's poses, with the reasons (as in
    `calibrate`); None where `parameters` were given. Under several processes every process fits the set of the
    first process that has robots (a process without any reports None)."""

    def uncertainty(self, r: int, source: str = "calibrate-fleet") -> jr.ModelUncertainty:
        """What the calibration leaves uncertain in robot `r` (`jaxrobot.ModelUncertainty`, the robot file's
        `[uncertainty]`, from its identification residuals: `identification.core._noise.model_uncertainty`)."""
        return model_uncertainty(self.names, self.value[r], self.covariance[r], float(self.noise_estimate[r]),
                                 float(self.chi2[r]), int(self.dof[r]), None, None, source)


def fleet_mesh(devices: Sequence | None = None) -> Mesh:
    """1-D device mesh over all (global) devices, axis name `"fleet"`."""
    return Mesh(np.asarray(jax.devices() if devices is None else devices), ("fleet",))


def _robot_residual_jacobian(robot, params, theta, positions, deflection, q0, marker, rippled, x, ccw=False):
    """Residual (n,) [mm] and Jacobian (n, m) of one robot at scaled parameters `x` by forward
    mode on `_residual_fn` (tool and base parameters, which the joint screws do not cover)."""
    fn, _, _ = _residual_fn(robot, params, theta, positions, None, deflection, marker, 1.0, ccw, rippled, q0)
    basis = jnp.eye(x.shape[0])
    r, cols = jax.vmap(lambda t: jax.jvp(lambda y: fn(y, None), (x,), (t,)), out_axes=(None, -1))(basis)
    return r, cols


def _screw_residual_jacobian(robots, params, theta, positions, deflection, q0, marker, rippled, v0, scale, x,
                             ccw=False):
    """Residuals (R, 3K) [mm] and Jacobian (R, 3K, m) of all robots at scaled parameters `x` from the
    joint screws (`position_jacobian` over robots and poses); rows are pose-major, as in
    `_robot_residual_jacobian` (row `3 k + c` is component `c` of pose `k`)."""
    robot = params.set(robots, v0 + scale * x)
    _, q_pose = joint_angle_model(robots, params, theta, deflection, False, rippled, q0)
    cc = jnp.zeros(theta.shape, bool) if ccw is False else ccw
    q = jax.vmap(jax.vmap(lambda rb, th, q0k, de, c: q_pose(rb, th, q0k, de, False if ccw is False else c),
                          (None, 0, 0, 0, 0)))(robot, theta, q0, deflection, cc)  # over robots, then poses
    if any(f"u0_{j + 1}" in params.names for j in rippled):
        ratio = jax.vmap(lambda rb, phi, c: jr.gear_ratio(rb, phi, False if ccw is False else c))(
            robot, q - deflection, cc)
    else:
        ratio = robot.u0[:, None]
    p, jac = position_jacobian(jax.tree.map(lambda f: f[:, None], robot), params, q, theta, ratio, marker)
    n_rob = x.shape[0]
    r = ((p - positions) / RESIDUAL_UNIT).reshape(n_rob, -1)
    return r, (jac * (scale / RESIDUAL_UNIT)[:, None, None, :]).reshape(n_rob, -1, x.shape[1])


CHUNK = {"cpu": 32, "accelerator": 4096}
"""Robots per chunk of the batched LM (`batched_lm(chunk=...)`), by backend: on the CPU a chunk's
Jacobians (32 x 150 x 25 for 50 poses, 1 MB) stay in cache; on an accelerator every chunk is a
sequential step of kernel launches, so chunks are large (`benchmarks/results_calibration.md`,
`benchmarks/results_gpu.md`)."""


def _chunk() -> int:
    return CHUNK[backend_kind()]


ROWS_MULTIPLE = 32
"""The robots of each device are padded to a multiple of this (copies of a robot, dropped after the
gather), so that fleets of other sizes share their compiled programs; on the CPU it is `CHUNK`, whose
last chunk the batched LM pads anyway."""


def _constants(robots, theta, rippled, ccw=False):
    """Per-pose constants of the solve, from the initial robots (thesis 3.2.3): the joint angles at
    rest `q0` (R, K, n) and the gravity deflection `q0 - Xi^{-1}(theta)` (R, K, n) (`rest_pose`;
    XLA evaluates the gear inversion once for both). `robots`: a fleet (R, ...) or one robot for all
    (then its fields are not broadcast over the poses); the gear inversion runs on the
    `rippled` joints only (the others are `theta / u0`); `ccw` (R, K, n) the direction of approach
    (False: every gear's `cw` set)."""
    fleet = robots if robots.a.ndim == 1 else jax.tree.map(lambda f: f[:, None], robots)
    q0 = rest_link_angles(fleet, theta, ccw, rippled=rippled, throw=False)  # NaN: stops as `nonfinite`
    return q0, q0 - jr.gear_output(fleet, theta, ccw, rippled=rippled)


def _local_solve(robots, theta, positions, marker, q0, defl, config, ccw=None, weight=None, x0=None, whiten=None,
                 frozen=None, *, params, rippled):
    """The fleet solve, batch-first: one `batched_lm` over all robots from scaled parameters `x0`
    (R, m) (default 0: the initial robots), then the covariances (`ccw`: as in `_constants`;
    `weight` (R, K): of each pose's squared residual, default 1; `whiten` (R, K, 3, 3): each pose's
    residual times it, default none; the returned residuals are whitened, not weighted; `frozen` (R,):
    robots not solved, whose rows of the result are meaningless, default none)."""
    v0 = jax.vmap(params.get)(robots)
    scale = jax.vmap(params.scales)(robots)
    screws = analytic_names(params.names)
    root_w = jnp.ones(theta.shape[:2]) if weight is None else jnp.sqrt(weight)

    white = () if whiten is None else (whiten,)

    def residual_jacobian(x, data):
        rb, th, pos, q, de, v, sc, rw, *rest = data
        wh, cc = (rest[0], rest[1:]) if white else (None, rest)
        if screws:
            r, jac = _screw_residual_jacobian(rb, params, th, pos, de, q, marker, rippled, v, sc, x, *cc)
        else:
            one = lambda r_, t_, p_, d_, q_, y_, *c_: _robot_residual_jacobian(  # noqa: E731
                r_, params, t_, p_, d_, q_, marker, rippled, y_, *c_)
            r, jac = jax.vmap(one)(rb, th, pos, de, q, x, *cc)
        if wh is not None:
            r = jnp.einsum("bkij,bkj->bki", wh, r.reshape(wh.shape[:3])).reshape(r.shape)
            jac = jnp.einsum("bkij,bkjp->bkip", wh, jac.reshape(wh.shape[:3] + jac.shape[-1:])).reshape(jac.shape)
        rows = jnp.repeat(rw, 3, axis=1)  # pose-major rows
        return r * rows, jac * rows[..., None]

    directed = () if ccw is None else (ccw,)
    out = batched_lm(residual_jacobian, jnp.zeros_like(v0) if x0 is None else x0,
                     (robots, theta, positions, q0, defl, v0, scale, root_w, *white, *directed), config,
                     chunk=_chunk(), frozen=frozen)
    n, m = out.residuals.shape[1], v0.shape[1]
    sigma2 = 2 * out.cost / max(n - m, 1)  # [mm^2], weighted
    residuals = out.residuals
    if weight is not None:  # unweighted: divided by the root weights, evaluated where a weight is 0 (or no fit)
        rows = jnp.repeat(root_w, 3, axis=1)
        evaluate = jnp.any(root_w == 0, 1) | ~jnp.isfinite(out.cost)
        evaluated = map_chunks(
            lambda a: residual_jacobian(a[0], (*a[1:8], jnp.ones_like(a[8]), *a[9:]))[0],
            (out.x, robots, theta, positions, q0, defl, v0, scale, root_w, *white, *directed), _chunk(),
            skip=~evaluate if frozen is None else ~evaluate | frozen)
        residuals = jnp.where(evaluate[:, None], evaluated, residuals / jnp.where(rows > 0, rows, 1.0))
    cov_x, rank, full = map_chunks(lambda a: covariance(*a), (out.normal, sigma2), _chunk(), skip=frozen)
    cov = cov_x * scale[:, :, None] * scale[:, None, :]
    finite = jnp.all(jnp.isfinite(out.x), 1) & jnp.all(jnp.isfinite(cov), (1, 2))
    ok = out.status == RESULTS.successful
    status = where(ok & ~finite, RESULTS.nonfinite, where(ok & ~full, RESULTS.rank_deficient, out.status))
    return ParameterEstimate(value=v0 + scale * out.x, std=jnp.sqrt(jnp.diagonal(cov, 0, 1, 2)), covariance=cov,
                             status=status, steps=out.steps, rank=rank, residuals=residuals * RESIDUAL_UNIT,
                             noise_variance=sigma2 * RESIDUAL_UNIT**2)


@eqx.filter_jit
def _fleet_constants(robots, theta, rippled, mesh, ccw=None):
    """`_constants`, every device on its own robots (`shard_map` over the `"fleet"` axis; one robot
    for all is replicated); `ccw` (R, K, n) or None (every gear's `cw` set)."""
    fleet = PartitionSpec("fleet")
    spec = PartitionSpec() if robots.a.ndim == 1 else fleet
    directed = () if ccw is None else (ccw,)
    return jax.shard_map(lambda r, t, *c: _constants(r, t, rippled, *c), mesh=mesh,
                         in_specs=(spec, fleet) + (fleet,) * len(directed), out_specs=fleet,
                         check_vma=False)(robots, theta, *directed)


@eqx.filter_jit
def _fleet_solve(robots, params, theta, positions, marker, q0, defl, config, rippled, mesh, ccw=None, weight=None,
                 x0=None, whiten=None, frozen=None):
    """`_local_solve`, every device on its own robots (`shard_map` over the `"fleet"` axis; each
    device's LM loop runs until its own robots have stopped); `config` (`LMConfig`) is traced; the
    `frozen` robots are placed last on each device, so that whole chunks of them cost nothing."""
    fleet, rep = PartitionSpec("fleet"), PartitionSpec()
    optional = {k: a for k, a in (("ccw", ccw), ("weight", weight), ("x0", x0), ("whiten", whiten),
                                  ("frozen", frozen)) if a is not None}

    def local(*args):
        if frozen is None:
            return _local_solve(*args[:7], **dict(zip(optional, args[7:])), params=params, rippled=rippled)
        order = jnp.argsort(args[-1], stable=True)
        args = [a if i in (3, 6) else jax.tree.map(lambda v: v[order], a) for i, a in enumerate(args)]
        out = _local_solve(*args[:7], **dict(zip(optional, args[7:])), params=params, rippled=rippled)
        return jax.tree.map(lambda v: v[jnp.argsort(order)], out)

    return jax.shard_map(local, mesh=mesh, in_specs=(fleet, fleet, fleet, rep, fleet, fleet, rep)
                         + (fleet,) * len(optional), out_specs=fleet,
                         check_vma=False)(robots, theta, positions, marker, q0, defl, config, *optional.values())


@jax.jit
def _pose_norms(residuals, sigma):
    """Whitened residual norm (R, K) of each pose from the residuals (R, 3K) [m] (pose-major)."""
    return jnp.linalg.norm(residuals.reshape(residuals.shape[0], -1, 3), axis=-1) / sigma


_set_parameters = eqx.filter_jit(ParameterMap.set)  # one compiled call instead of ~m eager scatters


@jax.jit
def _unchanged(weight, previous):
    """(R,) whether each robot's pose weights (R, K) equal its previous ones."""
    return jnp.all(weight == previous, -1)


@jax.jit
def _keep(frozen, previous, new):
    """The solve `new` with the rows of `previous` where `frozen` (R,)."""
    return jax.tree.map(lambda o, n: jnp.where(frozen.reshape((-1,) + (1,) * (n.ndim - 1)), o, n), previous, new)


@eqx.filter_jit
def _values_scales(params, robots):
    """The values (R, m) of the free parameters of the fleet `robots` and their scales (R, m)."""
    return jax.vmap(params.get)(robots), jax.vmap(params.scales)(robots)


@dataclasses.dataclass(frozen=True)
class _FleetPoses:
    """The checked poses of `calibrate_fleet` and what its measurement setup says of them."""

    theta: np.ndarray
    """(R, K, n) motor angles [rad]."""
    positions: np.ndarray
    """(R, K, 3) marker positions [m]."""
    ccw: np.ndarray
    """(R, K, n) bool: the direction of approach of each gear (all False: every gear's `cw` set)."""
    marker: Float[Array, "3"]
    """Marker offset [m] (`instruments`)."""
    noise: object
    """The tracker noise of `instruments` (`tracker_noise`)."""


def _fleet_poses(robots, motor_angles, positions, ccw, instruments, loss) -> _FleetPoses:
    """`calibrate_fleet`'s poses checked (shapes, finite values, `ccw`) with its setup and `loss`."""
    motor_angles, positions, quaternions, ccw = pose_arrays(motor_angles, positions, None, ccw)
    if quaternions is not None:
        raise ValueError("motor_angles: calibrate_fleet fits positions only; found Poses with quaternions "
                         "(give Poses without them, or calibrate each robot with `calibrate`)")
    marker = jnp.asarray(instruments.require("marker_offset", by="calibrate_fleet")[0], float)
    noise = tracker_noise(instruments, by="calibrate_fleet")
    robust.check_loss(loss)
    joints = robots.n_joints
    theta = np.asarray(motor_angles, float)
    pos = np.asarray(positions, float)
    if theta.ndim != 3 or theta.shape[-1] != joints:
        raise ValueError(f"motor_angles: expected shape (R, K, {joints}) in rad, found {theta.shape}")
    if pos.shape != theta.shape[:2] + (3,):
        raise ValueError(f"positions: expected shape {theta.shape[:2] + (3,)} in m, found {pos.shape}")
    if not (np.isfinite(theta).all() and np.isfinite(pos).all()):  # NaN rows, named by robot and pose
        for r in range(theta.shape[0]):
            _check_array(theta[r], (joints,), f"motor_angles[robot {r}]", "rad")
            _check_array(pos[r], (3,), f"positions[robot {r}]", "m")
    ccw = np.zeros(theta.shape, bool) if ccw is None else np.asarray(ccw)
    if ccw.shape != theta.shape or ccw.dtype != bool:
        raise ValueError(f"ccw: expected a bool array of shape {theta.shape} (robots, poses, joints), found "
                         f"{ccw.dtype} {ccw.shape}")
    return _FleetPoses(theta=theta, positions=pos, ccw=ccw, marker=marker, noise=noise)


def _fleet_parameters(robots, parameters, poses: _FleetPoses) -> tuple[ParameterMap, ParameterCheck | None]:
    """The free parameters: `parameters`, or the default set of the first robot checked on its poses (the
    check of the first process that has robots decides for all); and that check (None for `parameters`)."""
    n_rob, k = poses.theta.shape[:2]
    checked = None
    if parameters is None:
        first = robots if np.ndim(robots.a) == 1 else jax.tree.map(lambda x: x[0], robots)
        analysis = default_analysis(first, marker=poses.marker)
        parameters = default_set(analysis)
        keep = np.ones(len(parameters), bool)
        if n_rob:  # a process whose share was all left out has no poses to check the set on
            sigma0, white0 = noise_model(poses.noise, poses.positions[0], "instruments.tracker_noise")
            th0, ccw0 = jnp.asarray(poses.theta[0]), jnp.asarray(poses.ccw[0])
            checked = check_default(first, analysis, rest_pose(first, th0, ccw0)[0], poses.marker, white0, 1.0,
                                    sigma0)
            keep = np.array([p in checked.kept for p in parameters])
        # every process fits one set: the check of the first process that has robots decides
        has_robots, keeps = gather_array((np.array([n_rob > 0]), keep[None]))
        keep = np.asarray(keeps)[int(np.argmax(np.asarray(has_robots)))]
        parameters = tuple(p for p, k in zip(parameters, keep) if k)
    params = ParameterMap(parameters)
    if 3 * k < len(params):
        raise ValueError(f"motor_angles: {k} poses per robot give {3 * k} equations for {len(params)} "
                         f"parameters; need at least {-(-len(params) // 3)} poses")
    return params, checked


def _fit_fleet(initial, params, poses: _FleetPoses, mesh, max_steps, loss):
    """The LM solves of the fleet sharded over `mesh`, reweighted by a robust `loss`, gathered back; returns the
    solution, the fleet (leading axis R), the poses the loss kept (None for `l2`: every pose) and the per-axis
    tracker noise."""
    n_rob = poses.theta.shape[0]
    robots = initial  # one robot for all (its constants need no copy per robot), or the fleet
    if np.ndim(robots.a) == 1:
        robots = jax.tree.map(lambda x: jnp.broadcast_to(x, (n_rob,) + jnp.shape(x)), robots)
    elif robots.a.shape[0] != n_rob:
        raise ValueError(f"robots: expected one robot or a fleet of {n_rob}, found {robots.a.shape[0]}")
    sigma, white = noise_model(poses.noise, poses.positions.reshape(-1, 3), "instruments.tracker_noise")
    white = () if white is None else (white.reshape(poses.theta.shape[:2] + (3, 3)),)  # none: isotropic
    (g_robots, g_theta, g_pos, g_ccw, *g_white), origin = shard_rows(
        (robots, poses.theta, poses.positions, poses.ccw, *white), mesh, ROWS_MULTIPLE)
    g_white = g_white[0] if g_white else None
    rippled = rippled_joints(robots)
    g_ccw = g_ccw if poses.ccw.any() else None  # none: every gear's cw set, no selection per pose
    q0, defl = _fleet_constants(initial if np.ndim(initial.a) == 1 else g_robots, g_theta, rippled, mesh, g_ccw)
    config = jax.tree.map(jnp.asarray, LMConfig(max_steps=max_steps))
    solve = functools.partial(_fleet_solve, g_robots, params, g_theta, g_pos, poses.marker, q0, defl, config,
                              rippled, mesh, g_ccw)
    if loss == "l2":
        out, robots = gather_rows((solve(whiten=g_white), g_robots), origin)
        return out, robots, None, sigma
    v0, scale = _values_scales(params, g_robots)
    last = {"x0": jnp.zeros_like(v0), "weight": None, "out": None}  # every round runs one compiled solve

    def fit(weight):  # a robot whose weights did not change keeps its solution
        frozen = weight[:, 0] < 0 if last["out"] is None else _unchanged(weight, last["weight"])
        out = solve(weight, last["x0"], g_white, frozen)
        out = out if last["out"] is None else _keep(frozen, last["out"], out)
        last.update(x0=(out.value - v0) / scale, weight=weight, out=out)
        return out, _pose_norms(out.residuals, sigma)

    out, weight, settled = robust.irls(fit, jnp.ones_like(g_pos[..., 0]), loss, 3)
    out, robots, weight, settled = gather_rows((out, g_robots, weight, settled), origin)
    return eqx.tree_at(lambda o: o.status, out, robust.settled_status(out.status, settled)), robots, weight > 0, sigma


def calibrate_fleet(
    robots: jr.Robot,
    motor_angles: Float[Array, "R K n"] | Poses,
    positions: Float[Array, "R K 3"] | None = None,
    *,
    instruments: jr.Instruments,
    parameters: Sequence[str] | None = None,
    max_steps: int = 100,
    mesh: Mesh | None = None,
    ccw: Bool[Array, "R K n"] | None = None,
    loss: str = robust.LOSSES[0],
    throw: bool = False,
) -> FleetResult:
    """Calibrate R robots at once, each from its own K poses (positions only; at rest every gear's
    `cw` set, or the set of the direction of approach `ccw` (R, K, n) where given).

    `robots`: the initial robots, a fleet pytree with leading axis R, or one robot used for all.
    `motor_angles` (R, K, n) rad and `positions` (R, K, 3) m, or fleet `Poses` (leading axis R, as
    `jaxrobot.bench.measure_poses` of a fleet gives them) as `motor_angles`, then without `positions` and `ccw`.
    `instruments`: the measurement setup (`jaxrobot.Instruments`, as in `calibrate`: the marker offset and the
    tracker noise).
    The fleet axis is padded to `ROWS_MULTIPLE` robots per device and sharded over `mesh`
    (default: all devices). Robots whose solve failed or whose pose set is rank deficient have
    `converged = False` and their `status` says why (`throw`: raise the message of the first such
    status instead); so has a robot whose residuals exceed the stated noise (`inconsistent`: the
    chi-square test of `diagnose`, `identification.core._noise.noise_test`, at the level `ALPHA / R`).
    `max_steps`: of `LMConfig`. `parameters`: default `default_parameters` of the first robot, all of them for
    every robot (no backward elimination as in `calibrate`: one batched program over the robots). Under
    several processes (`jaxrobot.internal.initialize_processes`) each process passes only its own robots
    (e.g. rows `jaxrobot.internal.process_share(R)`, one robot or its own fleet rows in `robots`; none on a
    process whose robots all failed their checks) and every process receives the whole fleet in process
    order.

    `loss`: as in `calibrate` (robust by default, thresholds in units of the tracker noise of `instruments`: its
    per-axis std, or a laser tracker's model, whose covariance then whitens each pose's residual); each robot is
    reweighted on its own (a robot whose weights no longer change keeps its solution), its outliers and robust
    noise estimate are in `outliers` and `noise_estimate`.
    """
    poses = _fleet_poses(robots, motor_angles, positions, ccw, instruments, loss)
    params, checked = _fleet_parameters(robots, parameters, poses)
    mesh = fleet_mesh() if mesh is None else mesh
    out, robots, kept, sigma = _fit_fleet(robots, params, poses, mesh, max_steps, loss)
    resid = np.asarray(out.residuals).reshape(out.residuals.shape[0], -1, 3)
    chi2, dof, p_value = noise_test(resid, sigma, len(params), kept)
    level = ALPHA / len(p_value)
    status = where(np.asarray(out.status == RESULTS.successful) & (p_value <= level), RESULTS.inconsistent,
                   out.status)
    status = check(status, status, throw)
    noise = np.array([np.sqrt(v) if loss == "l2" else robust.noise_estimate(r, sigma, len(params))
                      for r, v in zip(resid, np.asarray(out.noise_variance))])
    cov = np.asarray(out.covariance) * (noise**2 / np.maximum(out.noise_variance, 1e-300))[:, None, None]
    resid = resid.reshape(resid.shape[0], -1)
    return FleetResult(
        robot=_set_parameters(params, robots, jnp.asarray(out.value)), value=out.value,
        std=np.sqrt(np.diagonal(cov, 0, 1, 2)), covariance=cov, converged=np.asarray(status == RESULTS.successful),
        status=status,
        iterations=out.steps, rank=out.rank, rms_m=np.sqrt(np.mean(resid**2, -1)), residuals=resid,
        names=params.names, n_devices=mesh.devices.size, loss=loss, noise_estimate=noise,
        outliers=tuple(robust.outliers(r.reshape(-1, 3), sigma) for r in resid), chi2=chi2, dof=dof,
        p_value=p_value, inconsistent_below=level, parameter_check=checked)
