"""The robot at rest: link angles held by given motor angles under gravity (SPEC.md,
"Static equilibrium"; thesis 3.2.3)."""

from __future__ import annotations

import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float

from ._dynamics import gravity_torque
from ._elasticity import elastic_deflection
from ._gear import gear_output
from ._robot import Robot

TOL = 1e-14
"""Fixed-point tolerance [rad]; the map contracts by |dg/dq| / k ~ 1e-3 per step."""


def rest_link_angles(
    robot: Robot, theta: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Link angles `q` at rest at motor angles `theta`: `kappa(phi - q) = g(q)`, `phi = Xi^{-1}(theta)`.

    Solved as the fixed point `q = phi - kappa^{-1}(g(q))` with optimistix (implicit
    derivatives). `ccw` selects the gear set of the last direction of approach.
    """
    phi = gear_output(robot, theta, ccw)

    def fn(q, args):
        robot, phi = args
        return phi - elastic_deflection(robot, gravity_torque(robot, q))

    sol = optx.fixed_point(fn, optx.FixedPointIteration(rtol=0.0, atol=TOL), phi, args=(robot, phi),
                           max_steps=64, throw=False)
    return jnp.where(sol.result == optx.RESULTS.successful, sol.value, jnp.nan)
