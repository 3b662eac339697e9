"""Virtual test bench, trajectory runs: the motor follows a commanded `theta(t)` exactly, the elastic model
of the as-built robot is integrated finely, and the optical tracker reports the marker position along the
path with Gaussian noise (the file format: `jaxrobot.io.write_trajectory_csv`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._kinematics import point_position
from .._robot import Robot
from .._simulate import simulate


def trajectory_run(
    robot: Robot,
    key: PRNGKeyArray,
    t: Float[Array, " N"],
    theta: Float[Array, "N n"],
    thetad: Float[Array, "N n"],
    thetadd: Float[Array, "N n"],
    marker: Float[Array, "3"],
    noise_m: float,
    substeps: int = 10,
) -> tuple[Float[Array, "N 3"], Float[Array, "N n"]]:
    """Tracker positions (N, 3) [m] of the marker and the true link angles (N, n) of `robot`
    following the commanded motor trajectory (direction-dependent gear sets, rest at start)."""
    q, _ = simulate(robot, t, theta, thetad, thetadd, substeps=substeps, directional=True)
    p = point_position(robot, q, jnp.asarray(marker))
    return p + noise_m * jax.random.normal(key, p.shape), q
