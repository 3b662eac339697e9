"""What `jaxrobot info` and the model stage of `jaxrobot demo` compute, in SI units: the gravity sag
and the elastic eigenfrequencies of a robot at given poses, and how closely the flat inverse of a
joint move tracks on the simulated robot (`_info` formats them)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._dynamics import flat_inverse
from .._gear import motor_angle
from .._kinematics import forward_kinematics
from .._modes import elastic_eigenfrequencies
from .._program_cache import cached_program
from .._robot import Robot
from .._simulate import simulate
from .._status import RESULTS, require_successful
from ..measurement._model import rest_solution


class PoseNumbers(eqx.Module):
    """A robot at P poses."""

    sag: Float[Array, " P"]
    """Flange displacement at rest when the motors are commanded `theta = Xi(q)` without deflection
    compensation [m]."""
    eigenfrequencies: Float[Array, "P m"] | None
    """Eigenfrequencies of the m elastic joints, linearised at rest with the motors and the rigid
    joints held, ascending [Hz]; None when every joint is rigid."""
    home: Float[Array, "4 4"]
    """Flange pose at `q = 0` [m]."""
    status: RESULTS
    """Status of the rest pose at each pose (`jaxrobot.measurement.rest_solution`)."""


@cached_program(static_argnames=("elastic",))
def _numbers(robot, q, elastic: tuple[int, ...]) -> PoseNumbers:
    q_rest, result = rest_solution(robot, motor_angle(robot, q))  # rigid command theta = Xi(q)
    p = forward_kinematics(robot, jnp.concatenate([q_rest, q]))[..., :3, 3]
    sag = jnp.linalg.norm(p[: len(q)] - p[len(q):], axis=-1)
    home = forward_kinematics(robot, jnp.zeros(robot.n_joints))
    if not elastic:
        return PoseNumbers(sag, None, home, result)
    return PoseNumbers(sag, elastic_eigenfrequencies(robot, q)[:, robot.n_joints - len(elastic):], home, result)


def pose_numbers(robot: Robot, q: Float[Array, "P n"]) -> PoseNumbers:
    """Gravity sag and elastic eigenfrequencies of `robot` at the poses `q` [rad] (`PoseNumbers`); raises
    the status message where a rest pose did not converge."""
    elastic = tuple(int(i) for i in np.flatnonzero(np.isfinite(np.asarray(robot.k1))))
    numbers = _numbers(robot, jnp.asarray(q, float), elastic)
    require_successful(numbers.status, "rest pose of the robot at a listed pose")
    return numbers


def _joint_move(qa, qb, duration):
    def q_d(t):
        s = jnp.clip(t / duration, 0.0, 1.0)
        return qa + (qb - qa) * (35 * s**4 - 84 * s**5 + 70 * s**6 - 20 * s**7)

    return q_d


@cached_program(static_argnames=("duration",))
def _move_flat_inverse(robot, qa, qb, duration, t):
    return flat_inverse(robot, _joint_move(qa, qb, duration), t)


@cached_program
def _move_simulation(robot, t, theta, thetad, thetadd, q0):
    return simulate(robot, t, theta, thetad, thetadd, substeps=4, q0=q0)


@cached_program(static_argnames=("duration",))
def _move_error(qa, qb, duration, q, t):
    return jnp.max(jnp.abs(q - jax.vmap(_joint_move(qa, qb, duration))(t)))


def move_tracking_error(robot: Robot, qa: Float[Array, " n"], qb: Float[Array, " n"], duration: float) -> float:
    """Largest `|q - q_d|` [rad] when the flat inverse of the 7th-order joint move from `qa` to `qb` [rad]
    in `duration` [s] (then 0.2 s at rest) drives the robot simulated with RK4 at 0.25 ms."""
    t = jnp.arange(0.0, duration + 0.2, 1e-3)
    th, thd, thdd = _move_flat_inverse(robot, qa, qb, duration, t)
    q0, result = jax.jit(rest_solution)(robot, th[0])
    require_successful(result, "rest pose at the start of the joint move")
    q, _ = _move_simulation(robot, t, th, thd, thdd, q0)
    return float(_move_error(qa, qb, duration, q, t))
