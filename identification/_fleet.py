"""Kinematic calibration of a fleet: thousands of robots in one call (thesis 3.2.3 at scale).

Every robot has its own poses and measurements; all robots are solved together by one
batch-first Levenberg-Marquardt loop (`_batched_lm`, on the residual and joint-screw Jacobian of
`_calibration._residual_fn`), each robot stopping on its own tolerances. The fleet axis is
sharded across all devices with `jax.sharding`
(a 1-D mesh named `"fleet"`), so that the same call uses one CPU, several GPUs, or several
hosts under `jax.distributed` (every process passes the full arrays; each device computes its
shard; results are gathered).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import Array, Float

import jaxrobot as jr

from ._batched_lm import STATUS, batched_lm, covariance
from ._calibration import DEFAULT_PARAMETERS, RESIDUAL_UNIT, _check_array, _residual_fn
from ._calibration_model import joint_angle_model, rippled_joints
from ._parameters import ParameterMap, rest_deflection
from ._pose_selection import default_marker


@dataclasses.dataclass(frozen=True)
class FleetResult:
    """Per-robot results (leading axis R): `robot` (calibrated fleet pytree), `value`, `std`
    (R, m), `covariance` (R, m, m), `converged` (status converged and full rank), `status`
    (R,) name from `_batched_lm.STATUS` (`converged`, `max_steps`, `non_finite`, or
    `rank_deficient`), `iterations` LM steps, `rank` (R,), `rms_m` residual rms (R,),
    `residuals` (R, 3K) [m], `names`."""

    robot: jr.Robot
    value: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    iterations: np.ndarray
    rank: np.ndarray
    rms_m: np.ndarray
    residuals: np.ndarray
    names: tuple[str, ...]
    n_devices: int


def fleet_mesh(devices: Sequence | None = None) -> Mesh:
    """1-D device mesh over all (global) devices, axis name `"fleet"`."""
    return Mesh(np.asarray(jax.devices() if devices is None else devices), ("fleet",))


def _to_global(x: np.ndarray, sharding: NamedSharding) -> Array:
    x = np.asarray(x)
    return jax.make_array_from_callback(x.shape, sharding, lambda idx: x[idx])


def _gather(x: Array) -> np.ndarray:
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)


def _robot_residual_jacobian(robot, params, theta, positions, deflection, q0, marker, rippled, x):
    """Residual (n,) [mm] and Jacobian (n, m) of one robot at scaled parameters `x` (`_residual_fn`)."""
    fn, _, _ = _residual_fn(robot, params, theta, positions, None, deflection, marker, 1.0, False, rippled, q0)
    basis = jnp.eye(x.shape[0])
    r, cols = jax.vmap(lambda t: jax.jvp(lambda y: fn(y, None), (x,), (t,)), out_axes=(None, -1))(basis)
    return r, cols


def _local_solve(robots, params, theta, positions, marker, max_steps, rippled):
    """The fleet solve, batch-first: the per-pose constants (gravity deflection, gear inversion
    of the joints with fixed `u0`) once, then one `batched_lm` over all robots."""
    defl = jax.vmap(rest_deflection)(robots, theta)
    q0 = jax.vmap(lambda rb, th, de: joint_angle_model(rb, params, th, de, False, rippled)[0])(robots, theta, defl)
    v0 = jax.vmap(params.get)(robots)
    scale = jax.vmap(params.scales)(robots)

    def residual_jacobian(x):
        return jax.vmap(lambda rb, th, p, de, q, y: _robot_residual_jacobian(rb, params, th, p, de, q, marker,
                                                                             rippled, y))(
            robots, theta, positions, defl, q0, x)

    out = batched_lm(residual_jacobian, jnp.zeros_like(v0), max_steps=max_steps)
    n, m = out["residuals"].shape[1], v0.shape[1]
    sigma2 = 2 * out["cost"] / max(n - m, 1)  # [mm^2]
    cov_x, rank, full = covariance(out["normal"], sigma2)
    cov = cov_x * scale[:, :, None] * scale[:, None, :]
    finite = jnp.all(jnp.isfinite(out["x"]), 1) & jnp.all(jnp.isfinite(cov), (1, 2))
    return {"value": v0 + scale * out["x"], "std": jnp.sqrt(jnp.diagonal(cov, 0, 1, 2)), "cov": cov,
            "converged": (out["status"] == 0) & full & finite, "status": out["status"], "steps": out["steps"],
            "rank": rank, "residuals": out["residuals"] * RESIDUAL_UNIT}


_fleet_solve = eqx.filter_jit(_local_solve)
"""Jitted fleet solve; with inputs sharded along the fleet axis, XLA partitions the batched
arrays so that every device works on its own robots."""


def calibrate_fleet(
    robots: jr.Robot,
    motor_angles: Float[Array, "R K 6"],
    positions: Float[Array, "R K 3"],
    *,
    parameters: Sequence[str] = DEFAULT_PARAMETERS,
    marker: Float[Array, "3"] | None = None,
    max_steps: int = 100,
    mesh: Mesh | None = None,
) -> FleetResult:
    """Calibrate R robots at once, each from its own K poses (positions only, `cw` gear set).

    `robots`: the initial robots, a fleet pytree with leading axis R, or one robot used for all.
    The fleet axis is padded to a multiple of the device count and sharded over `mesh`
    (default: all devices). Robots whose solve failed or whose pose set is rank deficient have
    `converged = False`.
    """
    params = ParameterMap(parameters)
    theta = np.asarray(motor_angles, float)
    pos = np.asarray(positions, float)
    if theta.ndim != 3 or theta.shape[-1] != 6:
        raise ValueError(f"motor_angles: expected shape (R, K, 6) in rad, found {theta.shape}")
    if pos.shape != theta.shape[:2] + (3,):
        raise ValueError(f"positions: expected shape {theta.shape[:2] + (3,)} in m, found {pos.shape}")
    for r in range(theta.shape[0]):  # NaN rows, named by robot and pose (cheap host check)
        _check_array(theta[r], (6,), f"motor_angles[robot {r}]", "rad")
        _check_array(pos[r], (3,), f"positions[robot {r}]", "m")
    n_rob, k = theta.shape[:2]
    if 3 * k < len(params):
        raise ValueError(f"motor_angles: {k} poses per robot give {3 * k} equations for {len(params)} "
                         f"parameters; need at least {-(-len(params) // 3)} poses")
    if np.ndim(robots.a) == 1:
        robots = jax.tree.map(lambda x: jnp.broadcast_to(x, (n_rob,) + jnp.shape(x)), robots)
    elif robots.a.shape[0] != n_rob:
        raise ValueError(f"robots: expected one robot or a fleet of {n_rob}, found {robots.a.shape[0]}")
    mesh = fleet_mesh() if mesh is None else mesh
    n_dev = mesh.devices.size
    pad = -n_rob % n_dev
    take = np.concatenate([np.arange(n_rob), np.zeros(pad, int)])  # pad with copies of robot 0
    sharding = NamedSharding(mesh, PartitionSpec("fleet"))
    leaves, tree = jax.tree.flatten(robots)
    g_robots = jax.tree.unflatten(tree, [_to_global(np.asarray(x)[take], sharding) for x in leaves])
    marker = jnp.asarray(default_marker() if marker is None else marker, float)
    out = _fleet_solve(g_robots, params, _to_global(theta[take], sharding), _to_global(pos[take], sharding),
                       marker, max_steps, rippled_joints(robots))
    out = {key: _gather(v)[:n_rob] for key, v in out.items()}
    value = out["value"]
    status = np.asarray(STATUS + ("rank_deficient",))[np.where(
        (out["status"] == 0) & (out["rank"] < len(params)), len(STATUS), out["status"])]
    return FleetResult(
        robot=params.set(robots, jnp.asarray(value)), value=value, std=out["std"], covariance=out["cov"],
        converged=out["converged"], status=status, iterations=out["steps"], rank=out["rank"],
        rms_m=np.sqrt(np.mean(out["residuals"] ** 2, -1)), residuals=out["residuals"], names=params.names,
        n_devices=n_dev)
