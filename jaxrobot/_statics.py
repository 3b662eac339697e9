"""The robot at rest: link angles held by given motor angles under gravity (docs/model.md
(B.2); thesis 3.2.3)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float

from ._dynamics import gravity_torque
from ._elasticity import elastic_deflection
from ._gear import gear_output
from ._robot import Robot
from ._status import RESULTS, check

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
    and the link lags by half the backlash against it (`phi -= backlash/2` after a positive move).
    `rippled`: as in `gear_output`.
    """
    phi = gear_output(robot, theta, ccw, rippled) - 0.5 * robot.backlash * approach_sign(ccw)

    def fn(q, args):
        robot, phi = args
        return phi - elastic_deflection(robot, gravity_torque(robot, q))

    sol = optx.fixed_point(fn, optx.FixedPointIteration(rtol=0.0, atol=TOL), phi, args=(robot, phi),
                           max_steps=64, throw=False)
    return sol.value, RESULTS.promote(sol.result)


def rest_link_angles(
    robot: Robot,
    theta: Float[Array, "*b n"],
    ccw: bool | Bool[Array, "*b n"] = False,
    rippled: tuple[int, ...] | None = None,
    throw: bool = True,
) -> Float[Array, "*b n"]:
    """Link angles `q` at rest at motor angles `theta` (`rest_solution`).

    `throw`: raise the status's message (at run time, also under `jit`) when the fixed point did
    not converge; False gives NaN there instead, for batched solves that report a non-finite
    start in their own status (the fleet calibration).
    """
    q, result = rest_solution(robot, theta, ccw, rippled)
    ok = result == RESULTS.successful
    return check(result, q, True) if throw else jnp.where(ok, q, jnp.nan)
