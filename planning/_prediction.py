"""The predicted tool position error of a plan on the robot, from what the identification of its model left
uncertain (`jaxrobot.ModelUncertainty`, the robot file's `[uncertainty]`).

The motor trajectory is fixed; the robot is the model with its identified parameters `p` off by `dp ~ N(0, C)`
(`C` their covariance). The tool position error along the path, `e(t; dp) = x(t; p + dp) - p_d(t)`, simulated
as the plant evaluation does (`jr.simulate` from rest), is linearised in `dp`: `e0(t) + J(t) dp`, `J` by forward
mode (`jax.jacfwd`, one pass for all `m` parameters) through the kinematics at the link angles simulated on the
model, the links' deflection from their gear outputs held (`"kinematic"`: the deflection changes with a
deviation by a relative ~1e-3, far below the error itself), or through the whole simulation (`"simulation"`,
several simulations' cost). Gaussian draws of `dp` give the
distribution of the largest error over the path, `max_t |e0(t) + J(t) dp|`; the residual the identification did
not explain (`ModelUncertainty.unexplained`, an RMS distance no parameter accounts for) is added to each draw as
its own term. `benchmarks/bench_coverage.py` checks the band against robots of the bench.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from functools import cache, partial

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr
from jaxrobot.internal import cached_program

from ._evaluation import MotorTrajectory, plant_substeps
from ._ik import JointPath
from ._padding import head, pad_edge, pad_grid, pad_zeros, padded_nodes
from ._trajectories import sample_path

DRAWS = 4000
"""Gaussian draws of the parameter deviations (the Monte-Carlo error of the 95th percentile's probability is
`sqrt(0.95 * 0.05 / DRAWS)`, 0.3 %)."""
QUANTILES = (0.5, 0.95)
"""The reported quantiles of the largest error."""
METHODS = ("kinematic", "simulation")
"""How `predict_on_robot` linearises the error in the parameters' deviations: `"kinematic"` with the links'
deflection from the gear outputs held at the model's (one simulation, then the kinematics' derivatives),
`"simulation"` by forward mode through the whole simulation (the deflection's change included, several
simulations' cost)."""


@dataclasses.dataclass(frozen=True)
class RobotPrediction:
    """The predicted tool position error of a motor trajectory on the robot [m] (`predict_on_robot`)."""

    max_p50: float
    """Median of the largest error over the path [m], the unexplained residual included."""
    max_p95: float
    """Its 95th percentile [m]."""
    parameters_p50: float
    """Median of the largest error from the identified parameters' uncertainty alone [m]."""
    parameters_p95: float
    """Its 95th percentile [m]."""
    unexplained: float
    """[m] the residual the identification did not explain (`jaxrobot.ModelUncertainty.unexplained`), added to
    every draw."""
    band: Float[np.ndarray, "2 N"]
    """[m] the median and 95th percentile of the error at each sample (the unexplained residual included)."""
    model_error: Float[np.ndarray, " N"]
    """[m] the error of the trajectory on the model itself (`dp = 0`)."""
    method: str
    """How the error was linearised (one of `METHODS`; Gaussian draws of the linearised error)."""
    draws: int
    """Number of draws."""


def _path_positions(robot: jr.Robot, uncertainty: jr.ModelUncertainty, t, traj: MotorTrajectory, deviation,
                    substeps: int, directional: bool) -> Float[Array, "N 3"]:
    """Tool positions along `traj` simulated from rest on the model moved by `deviation` (m,)."""
    plant = uncertainty.apply(robot, deviation)
    q, _ = jr.simulate(plant, t, traj.theta, traj.thetad, traj.thetadd, substeps=substeps, directional=directional)
    return jr.tool_pose(plant, q)[:, :3, 3]


@partial(cached_program, static_argnames=("substeps", "directional"))
def _through_simulation(robot, uncertainty, t, traj, substeps: int, directional: bool):
    """Positions `x(t; p)` (N, 3) and their Jacobian (N, 3, m) with respect to the parameters' deviations, by
    forward mode through the simulation."""
    fn = lambda dp: _path_positions(robot, uncertainty, t, traj, dp, substeps, directional)  # noqa: E731
    zero = jnp.zeros(len(uncertainty.names))
    return fn(zero), jax.jacfwd(fn)(zero)


@partial(cached_program, static_argnames=("substeps", "directional"))
def _kinematic(robot, uncertainty, t, traj, substeps: int, directional: bool):
    """Positions `x(t; p)` (N, 3) and their Jacobian (N, 3, m) with respect to the parameters' deviations with
    the links' deflection from the gear outputs held at the model's (one simulation on the model): a deviation
    moves the tool through the kinematics and the gear outputs `Xi^{-1}(theta)` only."""
    q, _ = jr.simulate(robot, t, traj.theta, traj.thetad, traj.thetadd, substeps=substeps, directional=directional)

    def fn(dp):
        moved = uncertainty.apply(robot, dp)
        return jr.tool_pose(moved, q + jr.gear_output(moved, traj.theta) - jr.gear_output(robot, traj.theta))[:, :3, 3]

    zero = jnp.zeros(len(uncertainty.names))
    return fn(zero), jax.jacfwd(fn)(zero)


_LINEARISATIONS = {"kinematic": _kinematic, "simulation": _through_simulation}


@partial(cached_program, static_argnames=("substeps", "directional"))
def _sampled(robot, uncertainty, t, traj, deviations, substeps: int, directional: bool):
    """Positions (D, N, 3) on the D robots moved by `deviations` (D, m), one after the other."""
    return jax.lax.map(lambda dp: _path_positions(robot, uncertainty, t, traj, dp, substeps, directional),
                       deviations)


def _padded(jp: JointPath, traj: MotorTrajectory):
    """The time grid and `traj` padded to `padded_nodes(N)` samples (the command held at rest), and `p_d` (N, 3)."""
    n = jp.t.shape[0]
    size = padded_nodes(n)
    t = pad_grid(jnp.asarray(jp.t, float), size)
    padded = MotorTrajectory(pad_edge(traj.theta, size), pad_zeros(traj.thetad, size), pad_zeros(traj.thetadd, size))
    return t, padded, np.asarray(sample_path(jp.path, jp.t)[0])


def _check(robot: jr.Robot, uncertainty: jr.ModelUncertainty, jp: JointPath,
           traj: MotorTrajectory) -> list[int]:
    """Check the arguments (`ValueError` naming the one that does not fit); the positions of `uncertainty`'s names
    among every entry of the robot (`ModelUncertainty.columns`)."""
    n = jp.t.shape[0]
    if np.shape(traj.theta) != (n, robot.n_joints):
        raise ValueError(f"trajectory: expected motor angles of shape ({n}, {robot.n_joints}) [rad] on the joint "
                         f"path's grid, found {np.shape(traj.theta)}")
    if not isinstance(uncertainty, jr.ModelUncertainty):
        raise ValueError(f"uncertainty: expected a jaxrobot.ModelUncertainty (jaxrobot.io.read_uncertainty), found "
                         f"{type(uncertainty).__name__}")
    columns = list(uncertainty.columns(robot.n_joints))  # names entries the robot has
    if np.shape(uncertainty.covariance) != (len(uncertainty.names),) * 2:
        raise ValueError(f"uncertainty.covariance: expected shape ({len(uncertainty.names)},) * 2, found "
                         f"{np.shape(uncertainty.covariance)}")
    return columns


@cache
def _every_entry(n_joints: int) -> jr.ModelUncertainty:
    """A zero uncertainty over every entry an uncertainty may name (`ModelUncertainty.entries`): the one argument of
    the compiled programs for any parameter set and calibration (its own names are `ModelUncertainty.columns`)."""
    m = len(jr.ModelUncertainty.entries(n_joints))
    return jr.ModelUncertainty(jr.ModelUncertainty.entries(n_joints), jnp.zeros(m), jnp.zeros((m, m)), jnp.zeros(()),
                               jnp.zeros(()))


def deviation_draws(uncertainty: jr.ModelUncertainty, draws: int, seed: int) -> np.ndarray:
    """(draws, m) Gaussian deviations of the parameters with their covariance (seeded; symmetric square root, so
    that a covariance of lower rank is drawn too)."""
    w, v = np.linalg.eigh(np.asarray(uncertainty.covariance, float))
    root = v * np.sqrt(np.clip(w, 0.0, None))
    return np.random.default_rng(seed).standard_normal((draws, len(w))) @ root.T


def _drawn_errors(e0: Float[np.ndarray, "N 3"], jac: Float[np.ndarray, "N 3 m"],
                  deviations: Float[np.ndarray, "D m"]) -> Float[np.ndarray, "D N"]:
    """[m] The linearised error's norm `|e0 + J dp|` at each sample for each of the deviations, 250 at a time (one
    matrix product each)."""
    n, m = e0.shape[0], jac.shape[-1]
    columns = jac.reshape(3 * n, m).T
    err = np.empty((len(deviations), n))
    for rows in np.array_split(np.arange(len(deviations)), max(1, len(deviations) // 250)):
        e = (deviations[rows] @ columns).reshape(len(rows), n, 3) + e0
        err[rows] = np.sqrt(np.einsum("dni,dni->dn", e, e))
    return err


def _linearised(robot, uncertainty, jp, trajectory, directional, method, substeps):
    """The error on the model `e0` (N, 3) and its Jacobian (N, 3, m) with respect to `uncertainty`'s parameters."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, found {method!r}")
    columns = _check(robot, uncertainty, jp, trajectory)
    n = jp.t.shape[0]
    t, padded, p_d = _padded(jp, trajectory)
    substeps = plant_substeps(robot, jp.q, float(jp.path.sample_time)) if substeps is None else substeps
    every = _every_entry(robot.n_joints)
    x0, jac = head(_LINEARISATIONS[method](robot, every, t, padded, substeps, bool(directional)), n)
    return np.asarray(x0) - p_d, np.asarray(jac)[..., columns]


def task_weight(robot: jr.Robot, names: Sequence[str], jp: JointPath, trajectory: MotorTrajectory,
                directional: bool = False, method: str = "kinematic",
                substeps: int | None = None) -> Float[np.ndarray, "m m"]:
    """The weight `W = mean_k J_k^T J_k` (m, m) of the task `jp` run by the motor `trajectory` on the model `robot`:
    `J_k` (3, m) the tool position error's Jacobian at sample `k` with respect to the parameters `names` (robot-file
    entries, `jaxrobot.ModelUncertainty.names`), linearised as `predict_on_robot` does (`method`, `directional`).
    For parameter deviations of covariance `C`, `trace(W C)` is the mean squared error along the task
    [m^2]; `identification.calibration.task_poses` chooses calibration poses that minimise it."""
    m = len(names)
    probe = jr.ModelUncertainty(tuple(names), jnp.zeros(m), jnp.zeros((m, m)), jnp.asarray(0.0), jnp.asarray(0.0))
    jac = _linearised(robot, probe, jp, trajectory, directional, method, substeps)[1]
    return np.einsum("nim,nik->mk", jac, jac) / jac.shape[0]


def predict_on_robot(robot: jr.Robot, uncertainty: jr.ModelUncertainty, jp: JointPath, trajectory: MotorTrajectory,
                     directional: bool = False, method: str = "kinematic", draws: int = DRAWS, seed: int = 0,
                     substeps: int | None = None) -> RobotPrediction:
    """The tool position error that the motor `trajectory` (planned on the model `robot` for the joint path `jp`)
    will show on the robot, as a distribution over what the model's identification left uncertain (the module
    docstring): the median and 95th percentile of the largest error over the path, and the band along it.
    `directional`: the gears with their states between their sets (`jr.simulate`), as `plan_task` evaluates the plant;
    `method`: the linearisation (`METHODS`); `draws` Gaussian draws from the generator seeded by `seed`; `substeps`:
    RK4 steps per sample of the simulations (default `plant_substeps` of `robot` along `jp`).
    Raises `ValueError` naming `trajectory`, `uncertainty` or `method` where they do not fit."""
    e0, jac = _linearised(robot, uncertainty, jp, trajectory, directional, method, substeps)
    unexplained = float(uncertainty.unexplained)
    err = _drawn_errors(e0, jac, deviation_draws(uncertainty, draws, seed))
    (p50, p95), band = np.quantile(err.max(-1), QUANTILES), np.quantile(err.T, QUANTILES, axis=1)
    return RobotPrediction(float(p50) + unexplained, float(p95) + unexplained, float(p50), float(p95), unexplained,
                           band + unexplained, np.linalg.norm(e0, axis=-1), method, draws)


def sampled_errors(robot: jr.Robot, uncertainty: jr.ModelUncertainty, jp: JointPath, trajectory: MotorTrajectory,
                   deviations: Float[Array, "D m"], directional: bool = False,
                   substeps: int | None = None) -> Float[np.ndarray, "D N"]:
    """[m] The tool position error of `trajectory` along `jp` simulated on each robot of the model moved by
    `deviations` (D, m) (the sampled counterpart of `predict_on_robot`'s linearisation)."""
    columns = _check(robot, uncertainty, jp, trajectory)
    n = jp.t.shape[0]
    t, padded, p_d = _padded(jp, trajectory)
    every = _every_entry(robot.n_joints)
    full = np.zeros((len(deviations), len(every.names)))
    full[:, columns] = np.asarray(deviations, float)
    substeps = plant_substeps(robot, jp.q, float(jp.path.sample_time)) if substeps is None else substeps
    x = _sampled(robot, every, t, padded, jnp.asarray(full), substeps, bool(directional))
    return np.linalg.norm(np.asarray(x)[:, :n] - p_d, axis=-1)
