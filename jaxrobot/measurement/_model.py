"""The measurement model (thesis 3.2.3, docs/model.md (B.2), (3.6)): the robot at rest at commanded
motor angles (link angles held under gravity by the elastic gears, with lost motion against the
direction of approach), and the pose of a marker fixed in the tool frame (`marker_pose`, a function of the
kinematics that `jaxrobot.measurement` exports with the rest). The bench, calibration and `diagnose` all call it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float

from .._dynamics import gravity_torque
from .._elasticity import elastic_deflection
from .._gear import gear_output
from .._kinematics import marker_pose
from .._robot import Robot
from .._status import RESULTS, check

TOL = 1e-11
"""Fixed-point tolerance on the last step [rad]. The map contracts by `L = |dg/dq| / k` per step (Racer-7:
`L <= 2e-3`, measured over 2000 feasible poses), so the error after the stop is below `L / (1 - L) TOL`
(2e-14 rad); four steps from `phi` (deflections up to 1.4e-3 rad), one fewer than a test on the error itself."""


def approach_sign(ccw: bool | Bool[Array, "*b n"]) -> Float[Array, "*b n"]:
    """+1 after a positive move (`cw`), -1 after a negative one."""
    return 1.0 - 2.0 * jnp.asarray(ccw, float)


def approach_directions(theta: Float[Array, "*b K n"]) -> Bool[Array, "*b K n"]:
    """Direction of approach of poses measured in this order (`ccw`, per joint).

    Pose `k` is approached from pose `k - 1`, the first from the zero position; a joint that
    does not move keeps the direction of its previous move (`cw` at the start).
    """
    theta = jnp.asarray(theta, float)
    prev = jnp.concatenate([jnp.zeros_like(theta[..., :1, :]), theta[..., :-1, :]], -2)
    step = jnp.sign(theta - prev)

    def keep(last, s):
        d = jnp.where(s == 0, last, s)
        return d, d

    _, d = jax.lax.scan(keep, jnp.ones(theta.shape[:-2] + theta.shape[-1:]), jnp.moveaxis(step, -2, 0))
    return jnp.moveaxis(d, 0, -2) < 0


def lost_motion(robot: Robot, ccw: bool | Bool[Array, "*b n"]) -> Float[Array, "*b n"]:
    """Offset of the link from the gear output against the direction of approach: half the backlash,
    `backlash/2` after a positive move (`cw`), `-backlash/2` after a negative one."""
    return 0.5 * robot.backlash * approach_sign(ccw)


def rest_map(robot: Robot, phi: Float[Array, "*b n"], q: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """One step of the rest fixed point, `phi - kappa^{-1}(g(q))` (the gears' deflection under the
    gravity torque at `q`)."""
    return phi - elastic_deflection(robot, gravity_torque(robot, q))


def rest_iterations(
    robot: Robot, phi: Float[Array, "*b n"], steps: int, q0: Float[Array, "*b n"] | None = None
) -> Float[Array, "*b n"]:
    """`steps` iterations of `rest_map` from `q0` (default `phi`): the rest angles unrolled, cheap to
    differentiate in forward mode."""
    return jax.lax.fori_loop(0, steps, lambda _, q: rest_map(robot, phi, q), phi if q0 is None else q0)


FIXED_POINT_STEPS = 6
"""Iterations of `q = phi - kappa^{-1}(g(q))` from `q = phi`; the map contracts by
`|dg/dq| / kappa' < 3e-3` per step on the Racer-7, so 6 steps reach float64 precision (the
same fixed point as `rest_link_angles`, unrolled so that `jvp` through it stays cheap)."""


def quasi_static_link_angles(
    robot: Robot, theta: Float[Array, " n"], ccw: Bool[Array, " n"]
) -> Float[Array, " n"]:
    """Link angles at rest at motor angles `theta`: the fixed point of
    `q = Xi^{-1}(theta) - kappa^{-1}(g(q))` (docs/model.md (B.2)), differentiable."""
    return rest_iterations(robot, gear_output(robot, theta, ccw), FIXED_POINT_STEPS)


def rest_solution(
    robot: Robot,
    theta: Float[Array, "*b n"],
    ccw: bool | Bool[Array, "*b n"] = False,
    rippled: tuple[int, ...] | None = None,
) -> tuple[Float[Array, "*b n"], RESULTS]:
    """Link angles `q` at rest at motor angles `theta` and the status of their fixed point
    (`RESULTS`, one per pose under `vmap`): `kappa(phi - q) = g(q)`, `phi = Xi^{-1}(theta)`.

    Solved as the fixed point `q = phi - kappa^{-1}(g(q))` with optimistix (implicit
    derivatives). `ccw` gives the last direction of approach per joint: it selects the gear set,
    and the link trails by half the backlash against it (`phi -= backlash/2` after a positive move).
    `rippled`: as in `gear_output`.
    """
    phi = gear_output(robot, theta, ccw, rippled) - lost_motion(robot, ccw)

    def fn(q, args):
        robot, phi = args
        return rest_map(robot, phi, q)

    sol = optx.fixed_point(fn, optx.FixedPointIteration(rtol=0.0, atol=TOL), phi, args=(robot, phi),
                           max_steps=64, throw=False)
    return sol.value, RESULTS.promote(sol.result)


def rest_link_angles(
    robot: Robot,
    theta: Float[Array, "*b n"],
    ccw: bool | Bool[Array, "*b n"] = False,
    rippled: tuple[int, ...] | None = None,
    throw: bool = False,
) -> Float[Array, "*b n"]:
    """Link angles `q` at rest at motor angles `theta` (`rest_solution`).

    Where the fixed point did not converge the angles are NaN, for batched solves that report a
    non-finite start in their own status (the fleet calibration); `throw=True` raises the status's
    message there instead (at run time, also under `jit`).
    """
    q, result = rest_solution(robot, theta, ccw, rippled)
    ok = result == RESULTS.successful
    return check(result, q, True) if throw else jnp.where(ok, q, jnp.nan)


def measured_pose(
    robot: Robot, theta: Float[Array, "*b n"], marker: Float[Array, "*b 3"], ccw: bool | Bool[Array, "*b n"] = False
) -> tuple[Float[Array, "*b n"], Float[Array, "*b 3"], Float[Array, "*b 3 3"], RESULTS]:
    """Noise-free measurement at motor angles `theta`: link angles at rest, the marker's position and
    rotation there (`marker_pose`) and the status of the rest fixed point (`rest_solution`; the
    caller raises on it, e.g. `jaxrobot.internal.require_successful`)."""
    q, result = rest_solution(robot, theta, ccw)
    return (q, *marker_pose(robot, q, marker), result)
